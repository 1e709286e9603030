import pytest


def pytest_configure(config: pytest.Config) -> None:
    # Registered here, beside the only tests that use it, so `-m "not benchmark_smoke"`
    # deselects them without a warning.
    config.addinivalue_line(
        "markers", "benchmark_smoke: runs a benchmark script end to end with --quick "
        "(tens of seconds in all; deselect with -m 'not benchmark_smoke')")
