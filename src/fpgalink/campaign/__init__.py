"""Campaigns: many scenarios on emulated robots, run as fast as they go, on every core or a
Dask cluster, each giving figures (step response, turn rate, go-to error, odometry against
truth, stops and losses) into one table, and each into an MCAP recording if asked
(docs/campaigns.md).

```python
from fpgalink.campaign import load_campaign, run_campaign
results = run_campaign(load_campaign("seed36.toml"))
```

Stands on the robot and the asyncio layer; the emulated robots come through ``emu://``.
"""

from __future__ import annotations

from fpgalink.campaign.runner import default_jobs, run_campaign
from fpgalink.campaign.scenario import Result, run_scenario
from fpgalink.campaign.spec import (
    Action,
    Campaign,
    CampaignError,
    ParamSetting,
    Scenario,
    load_campaign,
    parse_campaign,
)

__all__ = ["Action", "Campaign", "CampaignError", "ParamSetting", "Result", "Scenario",
           "default_jobs", "load_campaign", "parse_campaign", "run_campaign", "run_scenario"]
