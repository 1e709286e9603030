import atexit
import os
import tempfile
from collections.abc import Generator

import pytest
from hypothesis import HealthCheck, settings

from tests.support import serving

# Bounded examples keep CI fast; `HYPOTHESIS_PROFILE=long` digs deeper locally.
settings.register_profile("ci", max_examples=150, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("long", max_examples=5000, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

# rcl writes a log file for every ROS process (the node, the peers, the benchmarks' smoke
# run): into a directory of this run's own, gone with it, not ~/.ros/log or a fixed /tmp path.
_ROS_LOGS = tempfile.TemporaryDirectory(prefix="fpgalink-tests-ros-logs-")
os.environ.setdefault("ROS_LOG_DIR", _ROS_LOGS.name)
atexit.register(_ROS_LOGS.cleanup)



# Each test's `fpgaemu serve`s (tests/support/serving.py): their logs in the report of a test
# that failed, and any still running after the test stopped (one that forgot, or ended by an
# exception, leaves none behind).
_SERVE_MARK = pytest.StashKey[int]()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None
                            ) -> Generator[None, object, object]:
    item.stash[_SERVE_MARK] = serving.started()
    try:
        return (yield)
    finally:
        for server in serving.take_since(item.stash[_SERVE_MARK]):
            server.discard()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]
                              ) -> Generator[None, pytest.TestReport, pytest.TestReport]:
    report = yield
    if report.failed and _SERVE_MARK in item.stash:
        for server in serving.peek_since(item.stash[_SERVE_MARK]):
            report.sections.append((f"{server.describe()}: its log ({server.log})",
                                    server.log_text()))
    return report
