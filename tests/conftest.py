"""Shared fixtures, and how the suite is split between parallel workers (scripts/test runs ``-n 2``)."""

from __future__ import annotations

import pytest

from furuta_rt.config import RigConfig, load_rig

# Tests that run the real-time loop against a device (a pty, a mock process, an in-process device paced by the
# host's clock) or time the host: all of them run one after another on one worker, so they keep a core while the
# other worker computes (diagnose, design, replay). Files with a test marked ``hil`` join them whole.
REALTIME_FILES = {
    "test_bad_input.py", "test_compensation.py", "test_dataloss.py", "test_hil_mock.py", "test_hil_mock_firmware.py",
    "test_logger.py", "test_no_overwrite.py", "test_reliability_harness.py", "test_reliability_safety.py",
    "test_run_loop.py", "test_swingup_supervisor.py",
}


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under ``--dist loadgroup`` (pytest-xdist): the real-time tests form one group; every other module is a
    group of its own, so a module's fixtures (recordings, diagnoses) are made once, on one worker."""
    realtime = REALTIME_FILES | {item.path.name for item in items if item.get_closest_marker("hil")}
    for item in items:
        name = item.path.name
        item.add_marker(pytest.mark.xdist_group("realtime" if name in realtime else name.removesuffix(".py")))


@pytest.fixture
def thesis_rig() -> RigConfig:
    return load_rig("thesis")
