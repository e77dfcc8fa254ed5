"""An experiment plan: the excitation a run adds to balancing, segment by segment, and its tick-by-tick form.

A plan (TOML) is a list of segments run one after another once the pendulum has balanced ``settle_s``:

    mode = "balancing"      # the controller balances throughout; the plan moves its arm reference and adds to u
    settle_s = 2.0          # balancing before the first segment
    return_speed = 0.5      # rad/s: after the last segment the arm reference ramps back to 0 at this speed

    [[segment]]
    kind = "step"           # arm reference jumps to phi (rad) and holds
    phi = 0.3
    duration = 3.0

    [[segment]]
    kind = "ramp"           # arm reference moves to phi at speed (rad/s), then holds
    phi = -0.3
    speed = 0.5
    duration = 4.0

    [[segment]]
    kind = "sweep"          # constant-velocity sweep: the reference moves at ±speed between ±amplitude
    amplitude = 0.5
    speed = 0.4
    duration = 10.0

    [[segment]]
    kind = "chirp"          # u += amplitude·sin(2π∫f dt), f linear from f0 to f1 Hz
    amplitude = 0.05
    f0 = 0.5
    f1 = 5.0
    duration = 10.0

    [[segment]]
    kind = "dither"         # u += amplitude·sin(2π·frequency·t)
    amplitude = 0.05
    frequency = 20.0
    duration = 5.0

    [[segment]]
    kind = "hold"           # reference held, nothing added
    duration = 2.0

A hanging plan (``mode = "hanging"``, `experiment design --hanging`) runs open loop with the pendulum hanging: the
supervisor arms within arm_theta of θ = π, ``settle_s`` passes at u = 0, then the chirp, dither and hold segments'
torque is the whole command (no balancing, no arm reference); it trips beyond |θ − π| = SWING_LIMIT
(furuta_rt.experiment.hanging) as balancing trips beyond |θ|.

The reference segments (step, ramp, sweep, hold) also take ``dither`` (amplitude, u units) and ``dither_hz``: a
dither on top of the motion (a slow sweep with a dither tells a dead band from dry friction). Amplitudes are in the
actuator's command units (N m for a torque actuator, V for a DC motor).

The reference (φ_r, φ̇_r) enters eq. 5 as u = L·[θ, θ̇, φ − φ_r, φ̇ − φ̇_r]; the added u reaches the arm with the
controller's command (furuta_rt.controller.controller). ``Excitation`` is the plan at the control rate: one ``step``
per balancing tick, precomputed, so the real-time path only indexes lists.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from furuta_rt.errors import UserError

MODES = ("balancing", "hanging")  # hanging: open loop about θ = π, the torque segments only (experiment.hanging)
REFERENCE_KINDS = ("hold", "step", "ramp", "sweep")
TORQUE_KINDS = ("chirp", "dither")
KINDS = REFERENCE_KINDS + TORQUE_KINDS
EVENT_PREFIX = "experiment:"
METADATA_NAME = "experiment"

_KEYS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {  # kind: (required, optional) besides kind, duration
    "hold": ((), ("dither", "dither_hz")),
    "step": (("phi",), ("dither", "dither_hz")),
    "ramp": (("phi", "speed"), ("dither", "dither_hz")),
    "sweep": (("amplitude", "speed"), ("dither", "dither_hz")),
    "chirp": (("amplitude", "f0", "f1"), ()),
    "dither": (("amplitude", "frequency"), ()),
}


@dataclass(frozen=True)
class Segment:
    kind: str
    duration: float
    params: dict[str, float] = field(default_factory=dict)

    def describe(self, hanging: bool = False) -> str:
        """The segment in words (``hanging``: of an open-loop plan, where a hold is no torque)."""
        p = self.params
        dither = f" + dither {p['dither']:g} at {p.get('dither_hz', 0):g} Hz" if p.get("dither") else ""
        text = {
            "hold": "no torque (the pendulum swings freely)" if hanging else "hold the arm reference",
            "step": f"arm reference step to {p.get('phi', 0):g} rad",
            "ramp": f"arm reference ramp to {p.get('phi', 0):g} rad at {p.get('speed', 0):g} rad/s",
            "sweep": f"constant-velocity sweep ±{p.get('amplitude', 0):g} rad at {p.get('speed', 0):g} rad/s",
            "chirp": f"chirp {p.get('f0', 0):g}–{p.get('f1', 0):g} Hz of amplitude {p.get('amplitude', 0):g} on u",
            "dither": f"dither {p.get('amplitude', 0):g} at {p.get('frequency', 0):g} Hz on u",
            "return": f"arm reference back to 0 at {p.get('speed', 0):g} rad/s",
        }[self.kind]
        return f"{text}{dither}, {self.duration:g} s"

    def to_toml(self) -> str:
        lines = ["[[segment]]", f'kind = "{self.kind}"']
        lines += [f"{k} = {v!r}" for k, v in self.params.items()]
        lines.append(f"duration = {self.duration!r}")
        return "\n".join(lines)


@dataclass(frozen=True)
class Plan:
    segments: tuple[Segment, ...]
    mode: str = "balancing"
    settle_s: float = 2.0
    return_speed: float = 0.5
    note: str = ""  # what the plan is for (design writes the look-alike it separates)

    @property
    def duration(self) -> float:
        """Seconds from the first segment's start to the end of the return to 0."""
        return sum(s.duration for s in self.segments) + self.return_segment().duration

    def return_segment(self) -> Segment:
        end = self.final_reference()
        return Segment("return", abs(end) / self.return_speed, {"speed": self.return_speed})

    def final_reference(self) -> float:
        ref, _, _ = reference_and_torque(self, 100.0, with_return=False)
        return float(ref[-1]) if len(ref) else 0.0

    def to_toml(self) -> str:
        head = [f"# furuta-rt experiment plan{': ' + self.note if self.note else ''}",
                f'mode = "{self.mode}"', f"settle_s = {self.settle_s!r}", f"return_speed = {self.return_speed!r}"]
        if self.note:
            head.append(f"note = {self.note!r}".replace("'", '"'))
        return "\n".join(head) + "\n\n" + "\n\n".join(s.to_toml() for s in self.segments) + "\n"

    def describe(self) -> list[str]:
        hanging = self.mode == "hanging"
        lines = [f"{i}/{len(self.segments)} {s.kind}: {s.describe(hanging)}" for i, s in enumerate(self.segments, 1)]
        r = self.return_segment()
        if r.duration > 0:
            lines.append(f"then {r.describe()}")
        return lines


def _number(where: str, key: str, value: Any, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise UserError(f"{where}: {key} = {value!r} is not a finite number")
    if positive and not value > 0:
        raise UserError(f"{where}: {key} = {value!r} must be > 0")
    if nonneg and value < 0:
        raise UserError(f"{where}: {key} = {value!r} must be >= 0")
    return float(value)


def plan_from_dict(data: dict[str, Any], source: str = "plan") -> Plan:
    """A validated plan from parsed TOML (one-line UserError naming the key otherwise)."""
    known = {"mode", "settle_s", "return_speed", "note", "segment"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise UserError(f"{source}: unknown key {unknown[0]!r} (a plan has {', '.join(sorted(known))})")
    mode = data.get("mode", "balancing")
    if mode not in MODES:
        raise UserError(f"{source}: mode = {mode!r}; one of {', '.join(MODES)}")
    settle = _number(source, "settle_s", data.get("settle_s", 2.0), nonneg=True)
    ret = _number(source, "return_speed", data.get("return_speed", 0.5), positive=True)
    raw = data.get("segment")
    if not isinstance(raw, list) or not raw:
        raise UserError(f"{source}: no [[segment]]: a plan needs at least one segment")
    segments = []
    for i, seg in enumerate(raw, 1):
        where = f"{source}: segment {i}"
        if not isinstance(seg, dict):
            raise UserError(f"{where}: not a table")
        kind = seg.get("kind")
        if kind not in KINDS:
            raise UserError(f"{where}: kind = {kind!r}; one of {', '.join(KINDS)}")
        if mode == "hanging" and kind in REFERENCE_KINDS and kind != "hold":
            raise UserError(f"{where}: kind = {kind!r} moves the arm reference, which a hanging plan (open loop) does "
                            "not have; hanging plans take chirp, dither and hold")
        required, optional = _KEYS[kind]
        extra = sorted(set(seg) - {"kind", "duration", *required, *optional})
        if extra:
            raise UserError(f"{where} ({kind}): unknown key {extra[0]!r} (it takes {', '.join((*required, *optional))})")
        if "duration" not in seg:
            raise UserError(f"{where} ({kind}): no duration (seconds)")
        duration = _number(where, "duration", seg["duration"], positive=True)
        params: dict[str, float] = {}
        for key in required:
            if key not in seg:
                raise UserError(f"{where} ({kind}): {key} is missing")
            params[key] = _number(where, key, seg[key], positive=key not in ("phi",))
        for key in optional:
            if key in seg:
                params[key] = _number(where, key, seg[key], nonneg=True)
        if params.get("dither") and not params.get("dither_hz"):
            raise UserError(f"{where} ({kind}): dither = {params['dither']:g} needs dither_hz (its frequency)")
        if kind == "chirp" and params["f1"] <= params["f0"]:
            raise UserError(f"{where}: chirp f1 = {params['f1']:g} Hz must be above f0 = {params['f0']:g} Hz")
        segments.append(Segment(kind, duration, params))
    plan = Plan(tuple(segments), mode, settle, ret, str(data.get("note", "")))
    _check_reachable(plan, source)
    return plan


def _check_reachable(plan: Plan, source: str) -> None:
    """A ramp must reach its target and a sweep start inside its band within the segment."""
    ref = 0.0
    for i, s in enumerate(plan.segments, 1):
        p = s.params
        if s.kind == "step":
            ref = p["phi"]
        elif s.kind == "ramp":
            need = abs(p["phi"] - ref) / p["speed"]
            if need > s.duration + 1e-9:
                raise UserError(f"{source}: segment {i} (ramp): {abs(p['phi'] - ref):g} rad at {p['speed']:g} rad/s "
                                f"takes {need:.3g} s, longer than its duration {s.duration:g} s")
            ref = p["phi"]
        elif s.kind == "sweep" and abs(ref) > p["amplitude"]:
            raise UserError(f"{source}: segment {i} (sweep): the reference is at {ref:g} rad, outside ±{p['amplitude']:g}")


def load_plan(path: str | Path) -> Plan:
    """A plan file, read as every TOML input is (a regular file, bounded; one line otherwise)."""
    from furuta_rt.tomlfile import read_toml

    data, source = read_toml(path, kind="plan")
    return plan_from_dict(data, source)


def check_plan_limits(plan: Plan, *, u_limit: float, phi_limit: float, margin: float = 0.8) -> None:
    """Refuse a plan whose own excitation uses more than ``margin`` of the rig's |u| or |φ| limit (the loop's
    response comes on top: design predicts it; this is the floor every run checks)."""
    ref, _, u = reference_and_torque(plan, 100.0)
    peak_ref = float(np.max(np.abs(ref), initial=0.0))
    peak_u = float(np.max(np.abs(u), initial=0.0))
    if peak_ref > margin * phi_limit:
        raise UserError(f"the plan moves the arm reference to {peak_ref:.3g} rad, beyond {margin:.0%} of the "
                        f"rig's |φ| limit {phi_limit:.3g} rad")
    if peak_u > margin * u_limit:
        raise UserError(f"the plan adds up to {peak_u:.3g} to u, beyond {margin:.0%} of the actuator limit {u_limit:g}")


def reference_and_torque(plan: Plan, rate_hz: float, *, with_return: bool = True
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(φ_r, φ̇_r, u added) at ``rate_hz`` from the first segment's start, the return to 0 included."""
    h = 1.0 / rate_hz
    refs, dots, us = [], [], []
    ref = 0.0
    segments = list(plan.segments)
    for s in segments:
        n = max(1, round(s.duration * rate_hz))
        t = np.arange(n) * h
        p = s.params
        r = np.full(n, ref)
        rd = np.zeros(n)
        u = np.zeros(n)
        if s.kind == "step":
            r[:] = p["phi"]
        elif s.kind == "ramp":
            sign = math.copysign(1.0, p["phi"] - ref)
            r = np.where(sign * (ref + sign * p["speed"] * t) < sign * p["phi"], ref + sign * p["speed"] * t, p["phi"])
            rd = np.where(r != p["phi"], sign * p["speed"], 0.0)
        elif s.kind == "sweep":
            r, rd = _triangle(ref, p["amplitude"], p["speed"], t)
        elif s.kind == "chirp":
            f0, f1 = p["f0"], p["f1"]
            k = (f1 - f0) / s.duration
            u = p["amplitude"] * np.sin(2 * np.pi * (f0 * t + 0.5 * k * t * t))
        elif s.kind == "dither":
            u = p["amplitude"] * np.sin(2 * np.pi * p["frequency"] * t)
        if p.get("dither"):
            u = u + p["dither"] * np.sin(2 * np.pi * p["dither_hz"] * t)
        refs.append(r)
        dots.append(rd)
        us.append(u)
        if s.kind in ("step", "ramp"):
            ref = p["phi"]
        elif s.kind == "sweep":  # where the sweep is at the segment's end (the same at any rate)
            ref = float(_triangle(ref, p["amplitude"], p["speed"], np.array([s.duration]))[0][0])
    if with_return and ref != 0.0:
        speed = plan.return_speed
        n = max(1, math.ceil(abs(ref) / speed * rate_hz))
        t = np.arange(1, n + 1) * h
        sign = -math.copysign(1.0, ref)
        r = ref + sign * speed * t
        r = np.where(sign * r < 0, r, 0.0)
        refs.append(r)
        dots.append(np.where(r != 0.0, sign * speed, 0.0))
        us.append(np.zeros(n))
    return np.concatenate(refs), np.concatenate(dots), np.concatenate(us)


def _triangle(start: float, amplitude: float, speed: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A reference moving at ±speed between ±amplitude, from ``start`` going up first."""
    period = 4 * amplitude / speed
    x = (start + amplitude) / speed + t  # time along the upward leg from -amplitude
    phase = np.mod(x, period)
    up = phase < period / 2
    r = np.where(up, -amplitude + speed * phase, amplitude - speed * (phase - period / 2))
    return r, np.where(up, speed, -speed)


def segment_starts(plan: Plan, rate_hz: float) -> list[int]:
    """Tick index (from the first segment's start) where each segment, and the return to 0, begins."""
    out, n = [], 0
    for s in plan.segments:
        out.append(n)
        n += max(1, round(s.duration * rate_hz))
    if plan.final_reference() != 0.0:
        out.append(n)
    return out


class Excitation:
    """The plan at the control rate, stepped once per driven tick by the controller (``step``): balancing, or for a
    hanging plan (``open_loop``) each open-loop tick, its torque then the whole command.

    The first ``settle_s`` of balancing add nothing; then each tick returns (φ_r, φ̇_r, u added) of the plan;
    after the return to 0 it returns zeros and ``done`` is set. A segment's first tick leaves its text in
    ``message`` for the loop to log as an event (``take_message``)."""

    def __init__(self, plan: Plan, rate_hz: float) -> None:
        self.plan = plan
        self.open_loop = plan.mode == "hanging"
        ref, dot, u = reference_and_torque(plan, rate_hz)
        self._ref, self._dot, self._u = ref.tolist(), dot.tolist(), u.tolist()
        self._n = len(self._ref)
        self._settle = round(plan.settle_s * rate_hz)
        starts = segment_starts(plan, rate_hz)
        names = [*plan.segments, plan.return_segment()]
        count = len(plan.segments)
        self._marks = {
            start: f"{EVENT_PREFIX} segment {i + 1}/{count} {seg.kind} start: {seg.describe(self.open_loop)}" if i < count
            else f"{EVENT_PREFIX} return start: {seg.describe()}"
            for i, (start, seg) in enumerate(zip(starts, names, strict=False))
        }
        self._i = -self._settle
        self.message: str | None = None
        self.done = False

    @property
    def ticks(self) -> int:
        """Driven ticks (balancing, or open loop for a hanging plan) the plan needs, settling included."""
        return self._settle + self._n

    def step(self) -> tuple[float, float, float]:
        i = self._i
        self._i = i + 1
        if i < 0:
            return 0.0, 0.0, 0.0
        if i >= self._n:
            if not self.done:
                self.done = True
                self.message = f"{EVENT_PREFIX} end"
            return 0.0, 0.0, 0.0
        mark = self._marks.get(i)
        if mark is not None:
            self.message = mark
        return self._ref[i], self._dot[i], self._u[i]

    def take_message(self) -> str | None:
        m, self.message = self.message, None
        return m


def plan_of_log(metadata: dict[str, dict[str, str]]) -> Plan | None:
    """The plan a run executed (its "experiment" metadata), or None for a run without one."""
    meta = metadata.get(METADATA_NAME)
    if not meta or "plan" not in meta:
        return None
    return plan_from_dict(tomllib.loads(meta["plan"]), meta.get("source") or "the log's plan")


@dataclass(frozen=True)
class SegmentSpan:
    """Where one segment of a plan ran in a log: ticks [start, stop) and device seconds."""

    label: str  # "1/3 step", ..., "return"
    kind: str
    start: int
    stop: int
    t_start: float
    t_stop: float


def driven_state(plan: Plan) -> str:
    """The supervisor state in which the plan's excitation steps: "balancing", or "open_loop" for a hanging plan."""
    return "open_loop" if plan.mode == "hanging" else "balancing"


def segments_in_log(plan: Plan, state: np.ndarray, t: np.ndarray, rate_hz: float) -> list[SegmentSpan]:
    """The plan's segments located in a log's ticks: the excitation steps once per driven tick (``driven_state``),
    so segment k starts at driven tick settle + its offset (the same ticks the "experiment: segment" events mark)."""
    bal = np.flatnonzero(np.asarray(state) == driven_state(plan))
    settle = round(plan.settle_s * rate_hz)
    starts = segment_starts(plan, rate_hz)
    total = len(reference_and_torque(plan, rate_hz)[0])
    kinds = [s.kind for s in plan.segments] + ["return"]
    out = []
    for i, a in enumerate(starts):
        b = starts[i + 1] if i + 1 < len(starts) else total
        if settle + a >= len(bal):
            break  # the run ended (a trip, a stop) before this segment
        lo, hi = bal[settle + a], bal[min(settle + b, len(bal)) - 1] + 1
        label = f"{i + 1}/{len(plan.segments)} {kinds[i]}" if i < len(plan.segments) else "return"
        out.append(SegmentSpan(label, kinds[i], int(lo), int(hi), float(t[lo]), float(t[hi - 1])))
    return out
