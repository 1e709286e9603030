import os

from hypothesis import HealthCheck, settings

# Bounded examples keep CI fast; `HYPOTHESIS_PROFILE=long` digs deeper locally.
settings.register_profile("ci", max_examples=150, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("long", max_examples=5000, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
