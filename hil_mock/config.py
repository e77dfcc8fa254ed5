"""The mock's configuration: which rig, which effects, device behaviour and injected faults.

A mock TOML file (all tables optional)::

    rig = "thesis"                  # shipped rig name, or a rig TOML path (relative to this file)

    [effects.arm_coulomb]           # furuta_rt.model.effects vocabulary, on top of the rig's [effects]
    Fc = 0.3

    [device]
    rate_hz = 500                   # default: the rig's control.rate_hz
    watchdog_ms = 20
    seed = 0                        # sensor-noise generator (same seed = same run as the simulator)
    initial_theta = 0.05            # rad; the plant is held there until the first HELLO
    device_id = 0x4D4F434B          # "MOCK"
    substep_hz = 10000              # physics substep of the core simulator
    pacing = "realtime"             # realtime | free (as fast as possible) | lockstep (wait for each COMMAND)
    spin_us = 100                   # the longest busy-wait before a deadline (it covers the sleeps' steady overshoot)
    priority = "realtime"           # SCHED_FIFO for the device thread if permitted (else nice -10); or "normal"
    cpu = 1                         # pin the device thread to this CPU (default: not pinned)
    late_threshold_us = 250         # a tick starting later than this is counted late (default: period / 4)
    firmware = "c"                  # device logic: the microcontroller's C core built for this machine, or "python"
    plant = "compiled"              # the plant in C (furuta_rt/sim/csrc/plant.c), or "python": the reference simulator

    [faults]
    corrupt_rate = 0.0              # per device→host byte: flip one random bit
    drop_rate = 0.0                 # per device→host byte: drop it
    rx_corrupt_rate = 0.0           # the same for host→device bytes
    rx_drop_rate = 0.0
    delay_ms = 0.0                  # hold outgoing frames this long (FIFO, tick granularity)
    seed = 1
    schedule = ["stall@2.0:100ms", "reset@3.0", "disconnect@5"]

Command-line ``--effect``/``--fault``/``--rate`` override the file. Every mistake is a UserError with
one line naming the key and the fix.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from furuta_rt.config import RigConfig, load_rig, require_plausible
from furuta_rt.errors import UserError
from furuta_rt.model.effects import Effects, effects_from_assignments
from furuta_rt.tomlfile import read_toml
from hil_mock.faults import FaultEvent, parse_fault

MAX_RATE_HZ = 10_000
Probability = Annotated[float, Field(ge=0.0, le=1.0)]


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid")


class DeviceSettings(_Section):
    rate_hz: Annotated[int, Field(ge=1, le=MAX_RATE_HZ)] | None = None
    watchdog_ms: Annotated[int, Field(ge=1, le=65535)] = 20
    seed: int = 0
    initial_theta: float = 0.05
    device_id: Annotated[int, Field(ge=0, le=0xFFFFFFFF)] = 0x4D4F434B
    substep_hz: Annotated[float, Field(gt=0, le=1e6)] = 10_000.0
    pacing: Literal["realtime", "free", "lockstep"] = "realtime"
    spin_us: Annotated[float, Field(ge=0, le=2000)] = 100.0
    priority: Literal["normal", "realtime"] = "realtime"
    cpu: Annotated[int, Field(ge=0)] | None = None  # pin the device thread to this CPU (the host loop's, so that a round
    # trip between them waits for no other CPU); None: not pinned
    late_threshold_us: Annotated[float, Field(gt=0)] | None = None  # default: a quarter period
    firmware: Literal["python", "c", "board"] = "c"  # device logic: the C core (hil_mock.c_firmware),
    # hil_mock.firmware, or the flashed image on the register-level board model (hil_mock.board_model)
    plant: Literal["compiled", "python"] = "compiled"  # furuta_rt.sim.compiled (where it covers the model) or the
    # reference simulator


class FaultSettings(_Section):
    corrupt_rate: Probability = 0.0
    drop_rate: Probability = 0.0
    rx_corrupt_rate: Probability = 0.0
    rx_drop_rate: Probability = 0.0
    delay_ms: Annotated[float, Field(ge=0, le=10_000)] = 0.0
    seed: int = 1
    schedule: list[str] = []

    @field_validator("schedule")
    @classmethod
    def _parse_schedule(cls, value: list[str]) -> list[str]:
        for text in value:
            parse_fault(text)  # raises ValueError with the reason
        return value

    def events(self) -> list[FaultEvent]:
        return sorted((parse_fault(t) for t in self.schedule), key=lambda e: e.at)


class MockConfig(_Section):
    rig: str = "thesis"
    effects: Effects = Effects()
    device: DeviceSettings = DeviceSettings()
    faults: FaultSettings = FaultSettings()
    base_dir: Path | None = Field(default=None, exclude=True)

    def load_rig(self) -> RigConfig:
        """The rig this mock simulates (a relative path is taken relative to the mock file)."""
        rig = self.rig
        if self.base_dir is not None and rig.endswith(".toml") and not Path(rig).is_absolute():
            rig = str(self.base_dir / rig)
        return require_plausible(load_rig(rig), rig)  # a length in cm is refused here as furuta-rt run refuses it

    def rate_hz(self, rig: RigConfig) -> int:
        return self.device.rate_hz if self.device.rate_hz is not None else round(rig.control.rate_hz)


def _one_line(source: str, err: ValidationError) -> str:
    first = err.errors()[0]
    loc = ".".join(str(p) for p in first["loc"]) or "(top level)"
    msg = first["msg"].removeprefix("Value error, ")
    if first["type"] == "extra_forbidden":
        msg = "unknown key (check the spelling; see hil_mock/config.py for all keys)"
    more = f" (and {len(err.errors()) - 1} more problem(s))" if len(err.errors()) > 1 else ""
    got = first.get("input")
    got_text = f" (got {got!r})" if first["type"] != "extra_forbidden" and not isinstance(got, dict | list) else ""
    return f"{source}: key '{loc}': {msg}{got_text}{more}"


def config_from_dict(data: dict[str, Any], source: str = "mock config", base_dir: Path | None = None) -> MockConfig:
    try:
        cfg = MockConfig.model_validate(data)
    except ValidationError as err:
        raise UserError(_one_line(source, err)) from None
    return cfg.model_copy(update={"base_dir": base_dir})


def load_mock_config(path: str | Path) -> MockConfig:
    """Read a mock TOML file. Raises UserError (one line) on any problem."""
    p = Path(path)
    data, _ = read_toml(p, kind="mock config")
    return config_from_dict(data, str(p), p.parent)


def build_config(
    path: str | Path | None = None,
    *,
    rig: str | None = None,
    effects: list[str] | None = None,
    faults: list[str] | None = None,
    device: dict[str, Any] | None = None,
    fault_settings: dict[str, Any] | None = None,
) -> MockConfig:
    """File (optional) + overrides: ``effects`` as ``name.param=value`` strings (they win over the
    file's), ``faults`` as schedule strings (appended), ``device``/``fault_settings`` as key → value."""
    cfg = load_mock_config(path) if path is not None else MockConfig()
    data = cfg.model_dump(exclude={"base_dir"}, exclude_none=True)
    if rig is not None:
        data["rig"] = rig
    if effects:
        try:
            data["effects"] = effects_from_assignments(effects, cfg.effects).present()
        except ValidationError as err:
            raise UserError(_one_line("--effect", err)) from None
        except ValueError as err:
            raise UserError(f"--effect: {err}") from None
    data["device"].update({k: v for k, v in (device or {}).items() if v is not None})
    data["faults"].update({k: v for k, v in (fault_settings or {}).items() if v is not None})
    if faults:
        for text in faults:
            try:
                parse_fault(text)
            except ValueError as err:
                raise UserError(f"--fault {text!r}: {err}") from None
        data["faults"]["schedule"] = [*data["faults"]["schedule"], *faults]
    return config_from_dict(data, str(path) if path is not None else "hil-mock options", cfg.base_dir)
