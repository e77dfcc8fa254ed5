"""hil_mock: the rig's DAQ microcontroller, simulated, speaking firmware_protocol over a pseudo-terminal.

The physics is the core simulator (furuta_rt.sim.simulator) built with RigModel.from_config(rig,
effects); this package adds the firmware's protocol behaviour (firmware.py), real-time serving on a
pty (device.py), fault injection (faults.py), configuration (config.py) and the ``hil-mock`` CLI.
"""

from hil_mock.config import DeviceSettings, FaultSettings, MockConfig, build_config, load_mock_config
from hil_mock.device import DeviceStats, VirtualDevice
from hil_mock.faults import FaultEvent, LinkFaults, parse_fault
from hil_mock.firmware import Firmware
from hil_mock.launch import MockStartError, start_mock_subprocess, stop_mock_subprocess

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
