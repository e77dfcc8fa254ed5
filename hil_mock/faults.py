"""Fault injection for the reliability tests: a lossy link and scheduled device misbehaviour.

Link faults act on bytes (``LinkFaults``): each device→host byte is independently dropped with
probability ``drop_rate`` or has one random bit flipped with probability ``corrupt_rate``; the
``rx_*`` rates do the same to host→device bytes. Seeded, so a run is repeatable.

Scheduled faults (``FaultEvent``), written ``kind@time[:duration]``; time in seconds since the
first handshake, duration as ``100ms``, ``0.1s`` or ``0.1`` (seconds):

    stall@2.0:100ms     the firmware hangs: no ticks, no reads, no writes; output held; the plant runs on
    reset@3.0           the device reboots: output zero, faults cleared, idle until a new HELLO, seq from 0
    disconnect@5        the device vanishes: the pty master is closed (the host sees EOF/EIO)
    mute@2.0:50ms       every device→host byte is lost for the duration (the device keeps running)
    deaf@2.0:50ms       every host→device byte is lost for the duration (the watchdog will trip)
    friction_step@8:Fc=0.5   the arm's Coulomb friction becomes 0.5 N m from then on (a bearing that wears or
                        is re-greased; the adaptive compensation has to follow). Fs=… (breakaway, ≥ Fc) too.
    push@4.0[:DV]       an impulse on the pendulum: θ̇ jumps by DV rad/s (default 2·√(ε/α), enough to knock a
                        balanced pendulum over: the energy of a full turn)
"""

from __future__ import annotations

import random
import re
from dataclasses import dataclass

FAULT_KINDS = ("stall", "reset", "disconnect", "mute", "deaf", "friction_step", "push")
_NEEDS_DURATION = ("stall", "mute", "deaf")
FRICTION_STEP_PARAMS = ("Fc", "Fs")
"""What ``friction_step@T:NAME=V[,NAME=V]`` may set: the arm's Coulomb (sliding) level and its breakaway."""
_PARAMS_RE = re.compile(r"^(?P<kind>[a-z_]+)@(?P<at>[0-9.eE+-]+):(?P<params>[A-Za-z_]\w*=.*)$")
_FAULT_RE = re.compile(r"^(?P<kind>[a-z]+)@(?P<at>[0-9.eE+-]+)(?::(?P<dur>[0-9.eE+-]+)(?P<unit>ms|s)?)?$")


@dataclass(frozen=True, slots=True)
class FaultEvent:
    """One scheduled fault: ``kind`` at ``at`` seconds (since the first handshake), lasting ``duration`` s."""

    kind: str
    at: float
    duration: float = 0.0  # s; for a push, the θ̇ jump in rad/s (0: the default)
    params: tuple[tuple[str, float], ...] = ()  # friction_step: (name, value) pairs

    def __str__(self) -> str:
        if self.params:
            return f"{self.kind}@{self.at:g}:" + ",".join(f"{k}={v:g}" for k, v in self.params)
        return f"{self.kind}@{self.at:g}" + (f":{self.duration * 1e3:g}ms" if self.duration else "")


def parse_duration(text: str, unit: str | None) -> float:
    value = float(text)
    return value / 1000.0 if unit == "ms" else value


def _parse_friction_step(text: str, at_text: str, params: str) -> FaultEvent:
    form = "friction_step@seconds:Fc=N_m[,Fs=N_m], e.g. friction_step@8:Fc=0.5"
    try:
        at = float(at_text)
    except ValueError:
        raise ValueError(f"fault {text!r}: the time must be a number ({form})") from None
    values: dict[str, float] = {}
    for item in params.split(","):
        name, _, value = item.partition("=")
        name = name.strip()
        if name not in FRICTION_STEP_PARAMS:
            raise ValueError(f"fault {text!r}: friction_step sets {' or '.join(FRICTION_STEP_PARAMS)}, not {name!r} ({form})")
        try:
            values[name] = float(value)
        except ValueError:
            raise ValueError(f"fault {text!r}: {name} must be a number of N m ({form})") from None
        if not (values[name] >= 0 and values[name] < float("inf")):
            raise ValueError(f"fault {text!r}: {name} must be a finite torque >= 0 N m")
    if "Fc" not in values:
        raise ValueError(f"fault {text!r}: friction_step needs the new Coulomb level Fc ({form})")
    if "Fs" in values and values["Fs"] < values["Fc"]:
        raise ValueError(f"fault {text!r}: the breakaway Fs must be >= the sliding level Fc")
    if at < 0:
        raise ValueError(f"fault {text!r}: time must be >= 0")
    return FaultEvent("friction_step", at, params=tuple(values.items()))


def parse_fault(text: str) -> FaultEvent:
    """Parse ``kind@time[:duration]`` (``friction_step@time:Fc=V``). Raises ValueError naming the problem and
    the expected form."""
    p = _PARAMS_RE.match(text.strip())
    if p is not None and p["kind"] == "friction_step":
        return _parse_friction_step(text, p["at"], p["params"])
    if text.strip().startswith("friction_step@"):
        raise ValueError(f"fault {text!r}: friction_step needs the new level, e.g. friction_step@8:Fc=0.5")
    m = _FAULT_RE.match(text.strip())
    form = "kind@seconds[:duration], e.g. stall@2.0:100ms, reset@3, disconnect@5"
    if m is None:
        raise ValueError(f"fault {text!r} is not of the form {form}")
    kind = m["kind"]
    if kind not in FAULT_KINDS:
        raise ValueError(f"unknown fault {kind!r}; known faults: {', '.join(FAULT_KINDS)}")
    try:
        at = float(m["at"])
        duration = parse_duration(m["dur"], m["unit"]) if m["dur"] else 0.0
    except ValueError:
        raise ValueError(f"fault {text!r}: time and duration must be numbers ({form})") from None
    if at < 0 or duration < 0:
        raise ValueError(f"fault {text!r}: time and duration must be >= 0")
    if kind in _NEEDS_DURATION and duration <= 0:
        raise ValueError(f"fault {text!r}: {kind} needs a duration, e.g. {kind}@{at:g}:100ms")
    if kind == "push":
        if m["unit"]:
            raise ValueError(f"fault {text!r}: push takes a θ̇ jump in rad/s, e.g. push@{at:g}:8, not a duration")
        return FaultEvent(kind, at, float(m["dur"]) if m["dur"] else 0.0)
    if kind not in _NEEDS_DURATION and m["dur"]:
        raise ValueError(f"fault {text!r}: {kind} takes no duration")
    return FaultEvent(kind, at, duration)


class LinkFaults:
    """Byte-level corruption and loss in both directions, with counters. Rates may be changed live."""

    __slots__ = (
        "corrupt_rate",
        "deafened",
        "drop_rate",
        "muted",
        "rng",
        "rx_corrupt_rate",
        "rx_corrupted",
        "rx_drop_rate",
        "rx_dropped",
        "tx_corrupted",
        "tx_dropped",
    )

    def __init__(
        self,
        corrupt_rate: float = 0.0,
        drop_rate: float = 0.0,
        rx_corrupt_rate: float = 0.0,
        rx_drop_rate: float = 0.0,
        seed: int = 1,
    ) -> None:
        self.corrupt_rate = corrupt_rate
        self.drop_rate = drop_rate
        self.rx_corrupt_rate = rx_corrupt_rate
        self.rx_drop_rate = rx_drop_rate
        self.muted = False
        self.deafened = False
        self.rng = random.Random(seed)
        self.tx_corrupted = self.tx_dropped = self.rx_corrupted = self.rx_dropped = 0

    @property
    def active(self) -> bool:
        return bool(self.corrupt_rate or self.drop_rate or self.rx_corrupt_rate or self.rx_drop_rate
                    or self.muted or self.deafened)

    def tx(self, data: bytes) -> bytes:
        """Device → host bytes after the link."""
        if self.muted:
            self.tx_dropped += len(data)
            return b""
        if not (self.corrupt_rate or self.drop_rate):
            return data
        out, corrupted, dropped = self._mangle(data, self.corrupt_rate, self.drop_rate)
        self.tx_corrupted += corrupted
        self.tx_dropped += dropped
        return out

    def rx(self, data: bytes) -> bytes:
        """Host → device bytes after the link."""
        if self.deafened:
            self.rx_dropped += len(data)
            return b""
        if not (self.rx_corrupt_rate or self.rx_drop_rate):
            return data
        out, corrupted, dropped = self._mangle(data, self.rx_corrupt_rate, self.rx_drop_rate)
        self.rx_corrupted += corrupted
        self.rx_dropped += dropped
        return out

    def _mangle(self, data: bytes, corrupt: float, drop: float) -> tuple[bytes, int, int]:
        rand = self.rng.random
        out = bytearray()
        corrupted = dropped = 0
        for byte in data:
            r = rand()
            if r < drop:
                dropped += 1
                continue
            if r < drop + corrupt:
                byte ^= 1 << self.rng.randrange(8)
                corrupted += 1
            out.append(byte)
        return bytes(out), corrupted, dropped
