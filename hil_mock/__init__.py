"""hil_mock: the rig's DAQ microcontroller, simulated, speaking firmware_protocol over a pseudo-terminal.

The physics is the core simulator (furuta_rt.sim.simulator) built with RigModel.from_config(rig,
effects); this package adds the firmware's protocol behaviour (firmware.py), real-time serving on a
pty (device.py), fault injection (faults.py), configuration (config.py) and the ``hil-mock`` CLI.

The public names are imported lazily (``__getattr__``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from hil_mock.config import DeviceSettings, FaultSettings, MockConfig, build_config, load_mock_config
    from hil_mock.device import DeviceStats, VirtualDevice
    from hil_mock.faults import FaultEvent, LinkFaults, parse_fault
    from hil_mock.firmware import Firmware
    from hil_mock.launch import MockStartError, start_mock_subprocess, stop_mock_subprocess

_HOME = {
    "DeviceSettings": "config",
    "FaultSettings": "config",
    "MockConfig": "config",
    "build_config": "config",
    "load_mock_config": "config",
    "DeviceStats": "device",
    "VirtualDevice": "device",
    "FaultEvent": "faults",
    "LinkFaults": "faults",
    "parse_fault": "faults",
    "Firmware": "firmware",
    "MockStartError": "launch",
    "start_mock_subprocess": "launch",
    "stop_mock_subprocess": "launch",
}
"""Public name → the submodule that defines it, imported on first use (PEP 562)."""

__all__ = [
    "DeviceSettings",
    "DeviceStats",
    "FaultEvent",
    "FaultSettings",
    "Firmware",
    "LinkFaults",
    "MockConfig",
    "MockStartError",
    "VirtualDevice",
    "build_config",
    "load_mock_config",
    "parse_fault",
    "start_mock_subprocess",
    "stop_mock_subprocess",
]


def __getattr__(name: str) -> Any:
    """Import a public name's submodule on first use: whoever only launches the mock (the daemon's
    control process) loads ``hil_mock.launch`` alone, not the simulator behind it."""
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module 'hil_mock' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"hil_mock.{home}"), name)
    globals()[name] = value
    return value
