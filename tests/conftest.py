import atexit
import os
import tempfile

from hypothesis import HealthCheck, settings

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
