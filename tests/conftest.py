"""Shared fixtures, and how the suite is split between parallel workers (scripts/test runs ``-n 2``)."""

from __future__ import annotations

import os

import pytest

from furuta_rt.config import RigConfig, load_rig

# Modules that only compute (model, simulation, design, diagnosis, codecs, files): each is a group of its own and
# the two workers share them. Every other module (a real-time loop against a device: a pty, a mock process, an
# in-process device paced by the host's clock; a timed host) runs in one group, one test after another on one worker,
# so it keeps a core while the other worker computes; so does any module with a test marked ``hil``, and any new
# module until it is named here.
COMPUTE_FILES = {
    "test_c_codec.py", "test_command_path.py", "test_compiled_plant.py", "test_config.py", "test_convert.py",
    "test_coupling.py", "test_design.py", "test_effect_registry.py", "test_experiment_design.py", "test_friction.py",
    "test_help_readme.py", "test_io_mapping.py", "test_io_mcap.py", "test_limit_cycle.py", "test_model.py",
    "test_protocol.py", "test_replay.py", "test_replay_stats.py", "test_reproduction.py", "test_run_summary.py",
    "test_sensors_observer.py", "test_simulator.py", "test_supervisor.py", "test_swingup.py",
    "test_swingup_supervisor.py", "test_system_packages.py",
}


COMPUTE_NICE = 10
"""Niceness of a compute test's process (and what it starts) when the process may take it back: CFS then gives a
real-time test's processes that are not SCHED_FIFO (an in-process device thread, the logger, the pytest worker that
paces a scripted device) about nine tenths of a core the other worker's computing would otherwise halve."""


def _may_renice() -> bool:
    """Lowering niceness again needs CAP_SYS_NICE (root): without it a worker that ran a compute test would stay
    niced for the real-time tests it runs later, so nothing is reniced."""
    return hasattr(os, "setpriority") and os.geteuid() == 0


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    """Before the test's fixtures are made: a compute test runs niced, a real-time test at the normal priority."""
    if _may_renice():
        group = next((m.args[0] for m in item.iter_markers("xdist_group") if m.args), "realtime")
        os.setpriority(os.PRIO_PROCESS, 0, 0 if group == "realtime" else COMPUTE_NICE)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under ``--dist loadgroup`` (pytest-xdist): the real-time tests form one group; every compute module is a
    group of its own, so its fixtures (recordings, diagnoses) are made once, on one worker."""
    hil = {item.path.name for item in items if item.get_closest_marker("hil")}
    for item in items:
        name = item.path.name
        compute = (name.startswith("test_diagnose") or name in COMPUTE_FILES) and name not in hil
        item.add_marker(pytest.mark.xdist_group(name.removesuffix(".py") if compute else "realtime"))


@pytest.fixture
def thesis_rig() -> RigConfig:
    return load_rig("thesis")
