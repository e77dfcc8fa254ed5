"""The actuator's timing read from the arm's starts (the command latency measured).

The latency stage (furuta_rt.diagnose.stages.latency) times the actuator on the arm equation's rows. Where the arm rests and
a command step starts it — the commonest bench test, one voltage step from rest — those rows carry almost no timing:
the rows at the start are left out (the kernel reaches back into the rest), and what follows is a smooth run-up whose
phase a delay and an inertia trade. The start itself is sharp. With the command stepping at tick k, the arm leaves its
encoder count a latency plus a fraction of a tick later, and its next counts follow φ − φ_rest ≈ ½·a·(t − t_k − L)²:
on a rig whose encoder resolves a few counts per tick of travel, L is pinned to a fraction of a tick.

Per start — a command step of at least STEP_SHARE of the largest command, the arm still (within REST_COUNTS) for
REST_SECONDS before it and leaving by ONSET_COUNTS within ONSET_SECONDS after — the arm is simulated from rest with
the model found (furuta_rt.diagnose.stages.stickslip.simulate_arm: eq. 4 with the shared friction and actuator chain, the
pendulum teacher-forced) at total latencies on a quarter-tick grid, from the step until it has moved ONSET_COUNTS, and
compared with the measured counts. A latency is *consistent* with a start when the simulated arm never strays more
than MAX_STRAY counts from the measured count (the encoder's half count, with a quarter count of room for the model's
own small error over a few tens of counts). The latency is reported when the config's is consistent with none of the
starts — and leaves the arm at least EVIDENCE times as far from the counts as the best latency does on each (the
model's own error, not only the latency, moves the arm by fractions of a count: a gain ↔ inertia look-alike named the
wrong way left 1.8 counts at the config's latency against 0.95 at the best, a pendulum length 10 % off 0.77–1.23
against 0.42–0.72; the true latencies 2.1–9.4 against 0.47–0.66) — and the starts' best latencies agree within
SPREAD_TICKS; it is the mean of those optima, its standard error their scatter (at least a quarter tick over √12, the
grid's). One start suffices — it is one sharp event, not a statistical average — but each start must be explained: a
start no latency on the grid makes consistent (a model that is wrong elsewhere, a breakaway from stiction) stops the
stage. The stage runs only where the latency stage reported nothing, on a commanded recording.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.judgement.verify import quiet
from furuta_rt.diagnose.regression.fitting import vertex
from furuta_rt.diagnose.regression.states import Prepared, States
from furuta_rt.diagnose.stages.latency import LATENCY_EFFECTS
from furuta_rt.diagnose.stages.stickslip import Window, simulate_arm
from furuta_rt.model.effects import Effects, command_timing, latency_effect
from furuta_rt.model.rig import RigModel

STEP_SHARE = 0.2  # a command step of at least this share of the largest |command|
REST_SECONDS = 0.1  # the arm within REST_COUNTS of one count for this long before the step
REST_COUNTS = 1
ONSET_COUNTS = 20  # the start is followed until the arm has moved this many counts ...
ONSET_SECONDS = 0.1  # ... within this long after the step (else it is no start)
LEAD_TICKS = 3  # the simulation starts this many ticks before the step
MAX_STRAY = 0.75  # counts: a latency is consistent with a start when the simulated arm stays this close to the counts
# (the encoder's half count, and a quarter for the model's own error: the right model at the right latency stays within
# 0.47–0.66 counts on the realistic single steps; a gain ↔ inertia look-alike named in the wrong way strays 0.95 at best)
EVIDENCE = 3.0  # the config's latency must leave the arm this many times as far from the counts as the best does
SPREAD_TICKS = 0.5  # the starts' best latencies must agree within this
MAX_TICKS = 12.0  # the grid of total latencies, in ticks, from 0
MAX_STARTS = 8
GRID_STEP_TICKS = 0.25  # the delay line's resolution at the windows' 2 kHz substeps on a 500 Hz loop


@dataclass(frozen=True)
class Start:
    step: int  # tick of the command step
    window: Window


@dataclass
class OnsetTiming:
    """What the starts say: the total latency (s) that every start is consistent with, or why none."""

    starts: list[int]  # ticks of the command steps used
    total: float | None  # s, sample instant → torque acting
    se: float
    config_total: float
    stray_at_config: list[float]  # counts, per start
    best: list[float]  # s, per start
    reason: str
    stray_at_best: list[float] = field(default_factory=list)  # counts, per start

    def as_json(self) -> dict:
        return {"starts_s": self.starts, "total": self.total, "se": self.se, "config_total": self.config_total,
                "stray_at_config_counts": self.stray_at_config, "best_per_start": self.best,
                "stray_at_best_counts": self.stray_at_best, "reason": self.reason}


def starts(prep: Prepared) -> list[Start]:
    """The command steps that start the arm from rest (module docstring), at most MAX_STARTS, spread over the file."""
    u, lsb = prep.u, prep.phi_lsb
    if u is None or not np.any(u):
        return []
    cnt = np.round(prep.phi / lsb)
    rest, onset = round(REST_SECONDS / prep.dt), round(ONSET_SECONDS / prep.dt)
    big = STEP_SHARE * float(np.max(np.abs(u)))
    valid = prep.valid
    out: list[Start] = []
    for k in np.flatnonzero(np.abs(np.diff(u)) >= big) + 1:
        a, b = k - rest - LEAD_TICKS, k + onset
        if a < 0 or b >= len(u) or not valid[a:b].all():
            continue
        before = cnt[a : k + 1]
        if before.max() - before.min() > REST_COUNTS:
            continue
        moved = np.flatnonzero(np.abs(cnt[k:b] - cnt[k]) >= ONSET_COUNTS)
        if not len(moved):
            continue
        start = k - LEAD_TICKS
        out.append(Start(int(k), Window(start, int(moved[0]) + LEAD_TICKS + 1, int(k), phi_dot=0.0)))
    if len(out) > MAX_STARTS:
        out = [out[i] for i in np.linspace(0, len(out) - 1, MAX_STARTS).round().astype(int)]
    return out


def _with_total(found: dict[str, dict[str, float]], total: float, lag: float) -> dict[str, dict[str, float]]:
    """``found`` with the total latency ``total`` (s): an input_delay on top of the config's lag, or a
    command_latency (the total) when shorter (effects.latency_effect)."""
    eff = {k: v for k, v in found.items() if k not in LATENCY_EFFECTS}
    name, delay = latency_effect(total, lag)
    eff[name] = {"delay": delay}
    return eff


def _model(rig: RigConfig, eff: dict[str, dict[str, float]]) -> RigModel:
    return RigModel.from_config(quiet(rig), Effects.model_validate(eff))


def stray(model: RigModel, prep: Prepared, fine: States, s: Start) -> float:
    """The largest distance (counts) of the arm simulated with ``model`` from the measured counts over the start."""
    w = s.window
    sim = simulate_arm(model, prep, fine, w)
    return float(np.max(np.abs(sim - prep.phi[w.start + 1 : w.start + 1 + w.horizon])) / prep.phi_lsb)


def assess(rig: RigConfig, found: dict[str, dict[str, float]], prep: Prepared, fine: States) -> OnsetTiming | None:
    """The total latency the arm's starts pin (module docstring); None without a start."""
    ss = starts(prep)
    if not ss or not prep.commanded:
        return None
    h, lag = prep.dt, prep.command_lag
    ticks, delay = command_timing(round(lag / h), float(found.get("input_delay", {}).get("delay", 0.0)),
                                  float(found["command_latency"]["delay"]) if "command_latency" in found else None)
    config_total = ticks * h + delay
    grid = np.arange(0.0, MAX_TICKS + 1e-9, GRID_STEP_TICKS) * h
    config_model = _model(rig, found)
    at_config = [stray(config_model, prep, fine, s) for s in ss]
    models = [_model(rig, _with_total(found, float(g), lag)) for g in grid]  # one per latency, shared by the starts
    times = [s.step * h for s in ss]
    best: list[float] = []
    at_best: list[float] = []
    se = GRID_STEP_TICKS * h / np.sqrt(12)

    def result(total: float | None, reason: str) -> OnsetTiming:
        return OnsetTiming(times, total, se, config_total, at_config, best, reason, at_best)

    for s in ss:
        strays = np.array([stray(m, prep, fine, s) for m in models])
        i = int(np.argmin(strays))
        at_best.append(float(strays[i]))
        if strays[i] > MAX_STRAY:
            return result(None, f"the start at t = {s.step * h:.3f} s is not explained at any latency (the arm strays "
                                f"{strays[i]:.1f} counts at best): the model found is not right there")
        best.append(vertex(grid, strays, i))
    total = float(np.mean(best))
    if len(best) > 1:
        se = max(float(np.std(best, ddof=1) / np.sqrt(len(best))), se)
    if max(best) - min(best) > SPREAD_TICKS * h:
        return result(None, f"the starts disagree: best latencies {min(best) / h:.2f}–{max(best) / h:.2f} ticks")
    if min(at_config) <= MAX_STRAY:
        return result(None, "the config's latency is consistent with the starts")
    if any(c < EVIDENCE * b for c, b in zip(at_config, at_best, strict=True)):
        return result(None, f"the config's latency is not far enough from the starts (the simulated arm strays less "
                            f"than {EVIDENCE:g}× as far as at the best latency)")
    return result(total, f"{len(ss)} start(s) from rest pin the total latency at {total / h:.2f} ticks "
                         f"({1e3 * total:.2f} ms; the config's {config_total / h:.2f} ticks leaves the simulated arm "
                         f"≥ {min(at_config):.1f} counts from the encoder's)")
