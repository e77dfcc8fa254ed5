"""`diagnose`: locate the mismatch between eq. 4 and a recording, name the missing physics, fit it, and
show the fit improve.

A diagnosis is the recording prepared once (stages/start.py: θ reconstructed through the inverse Bessel path, states,
accelerations and the held command seen through one Gaussian kernel) and then the stages of PIPELINE, in order, each
reading one immutable State and returning it changed (stages/state.py). Every physical model comes from
furuta_rt.model / furuta_rt.sim. The rig's own [effects] are part of the nominal model; what is found is reported as
corrected totals.

A new stage is one module under furuta_rt/diagnose/stages/ with ``stage(state) -> State`` and one line in PIPELINE.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.judgement import verdict
from furuta_rt.diagnose.judgement.locate import describe
from furuta_rt.diagnose.regression.library import ARM, Context
from furuta_rt.diagnose.regression.selection import EquationModel
from furuta_rt.diagnose.stages import (
    arm_rests,
    arm_starts,
    armlock,
    closed_loop,
    command_levels,
    consistency,
    equations,
    fit_metric,
    free_decay,
    identification,
    lookalikes,
    onset,
    peak_windows,
    peaks,
    practical_size,
    prediction_gate,
    stick_windows,
    stickslip,
    verdicts,
)
from furuta_rt.diagnose.stages.decay import DecayResult
from furuta_rt.diagnose.stages.findings import EquationResult, Found, Options, effects_of
from furuta_rt.diagnose.stages.start import start
from furuta_rt.diagnose.stages.state import State
from furuta_rt.model.effects import Effects
from furuta_rt.recording import Recording

Stage = Callable[[State], State]

PIPELINE: tuple[Stage, ...] = (
    equations.stage,  # each equation of eq. 4 regressed on the library's effects
    stick_windows.first_reading,  # the arm's sticks and breakaways: breakaway torque, actuator timing
    stick_windows.reselect,  # after a breakaway: the arm regression again without its short stays at one count
    stick_windows.second_reading,  # ... and the windows read again on top of that sliding level
    arm_starts.stage,  # the arm's starts from rest time the actuator, where no latency was found
    peak_windows.stage,  # the largest commands: an actuator torque limit
    lookalikes.stage,  # each effect against its look-alikes; the favoured one becomes the model
    free_decay.stage,  # a pendulum free decay tells viscous from Coulomb pivot friction
    prediction_gate.stage,  # what predicts held-out windows worse is moved out
    practical_size.stage,  # what is too small to matter is reported apart
    arm_rests.stage,  # the arm's rests against a torque: dry friction or a dead band
    command_levels.stage,  # a command of one magnitude: an input gain is a dead band's look-alike
    consistency.stage,  # the found effects as one simulable set
    fit_metric.stage,  # the nominal against the augmented model on the held-out windows
    closed_loop.stage,  # the controller's own run re-simulated with both models
    verdicts.stage,  # each equation: noise, or a misfit the library does not explain
    identification.stage,  # the arm's jointly calibrated parameters and what the data pins
)


def diagnose(rec: Recording, rig: RigConfig, options: Options | None = None) -> Diagnosis:
    """Diagnose ``rec`` against ``rig``: the stages of PIPELINE in order (see the module docstring)."""
    t0 = time.perf_counter()
    state = start(rec, rig, options or Options())
    for stage in PIPELINE:
        state = stage(state)
    return Diagnosis.of(state, seconds=time.perf_counter() - t0)


@dataclass
class Diagnosis:
    effects: list[Found]
    fit: dict
    located: str
    ambiguities: list[dict]
    lookalikes: list[dict]
    equations: dict[str, EquationResult]
    closed_loop: dict | None
    notes: list[str]
    seconds: float
    rig: str
    context: Context = field(repr=False)
    models: dict[str, EquationModel] = field(default_factory=dict, repr=False)
    decay: dict | None = None  # the free-decay analysis, when the recording is one
    decay_result: DecayResult | None = field(default=None, repr=False)
    prediction: dict = field(default_factory=dict, repr=False)  # starts, horizon, train effects (for figures)
    stick: stickslip.WindowStage | None = field(default=None, repr=False)  # the stick–slip windows, when there are sticks
    peak: stickslip.WindowStage | None = field(default=None, repr=False)  # the command-peak windows, when they ran
    starts: onset.OnsetTiming | None = field(default=None, repr=False)  # the arm's starts from rest, when they timed it
    not_predictive: list[dict] = field(default_factory=list)  # effects the prediction gate moved out (gate.run)
    verdicts: dict[str, verdict.EquationVerdict] = field(default_factory=dict, repr=False)  # per equation
    summary: str = ""  # one line: the verdicts (furuta_rt.diagnose.judgement.verdict)
    identification: dict | None = None  # the arm's jointly calibrated parameters and identifiable combinations
    below_practical: list[dict] = field(default_factory=list)  # effects too small to matter (judgement.practical)
    arm_lock: dict | None = None  # the arm's rests against a torque: dry friction or a dead band (stages.armlock)

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.effects]

    @classmethod
    def of(cls, s: State, seconds: float) -> Diagnosis:
        """The report of a pipeline's final State."""
        found = list(s.found)
        located = "; ".join(describe(r.location, list(r.selected.spec.effects)) for r in s.res.values())
        if s.stick is not None:
            located += "; " + stickslip.describe(s.stick, {f.name: f.params for f in found})
        if s.peak is not None and s.peak.added:
            located += "; " + peaks.describe(s.peak)
        res, verdicts = dict(s.res), dict(s.verdicts)
        return cls(
            effects=found, fit=dict(s.fit), located=verdict.with_verdicts(located, res, verdicts),
            ambiguities=list(s.ambiguities), lookalikes=list(s.lookalikes), equations=res, closed_loop=s.closed_loop,
            notes=list(s.notes), seconds=seconds, rig=s.rig.name, context=s.ctx, models=dict(s.ems),
            prediction=dict(s.prediction), decay=s.decay_report,
            decay_result=s.decay, stick=s.stick, peak=s.peak, starts=s.starts,
            not_predictive=s.gated.not_predictive if s.gated is not None else [], verdicts=verdicts,
            summary=verdict.summary(verdicts) + armlock.summary_clause(
                s.arm_lock, verdicts.get(ARM) is not None and verdicts[ARM].verdict != "not_assessed"),
            identification=s.identification, below_practical=list(s.below_practical),
            arm_lock=s.arm_lock.as_json() if s.arm_lock is not None else None,
        )

    def found_effects(self) -> Effects:
        return effects_of(self.effects)

    def to_json(self) -> dict:
        """One JSON-ready object (non-finite numbers become null)."""
        return plain(self._json())

    def _json(self) -> dict:
        return {
            "summary": self.summary,
            "effects": [e.as_json() for e in self.effects],
            "fit": {k: self.fit[k] for k in FIT_KEYS},
            "not_predictive": self.not_predictive,
            "below_practical_size": self.below_practical,
            "located": self.located,
            "ambiguities": self.ambiguities,
            "lookalikes": self.lookalikes,
            "identification": self.identification,
            "evidence": [
                {"name": e.name, "equation": e.equation, "source": e.source, "cv_gain": e.cv_gain, "t": e.t, "se": e.se,
                 "pinned": e.pinned, "pinned_combinations": e.combinations}
                for e in self.effects
            ],
            "free_decay": self.decay,
            "arm_rests": self.arm_lock,
            "stick_windows": self.stick.as_json() if self.stick is not None else None,
            "peak_windows": self.peak.as_json() if self.peak is not None else None,
            "arm_starts": self.starts.as_json() if self.starts is not None else None,
            "fit_details": {k: v for k, v in self.fit.items() if k not in FIT_KEYS},
            "closed_loop": self.closed_loop,
            "equations": {
                eq: {
                    "rows": r.rows, "nominal_rms": r.nominal.fit.cv_rms, "augmented_rms": r.selected.fit.cv_rms,
                    "cv_gain": r.gain, "relative_residual": r.location.relative_rms,
                    "correlations": r.location.correlations, "regions": r.location.regions,
                    **(self.verdicts[eq].as_json() if eq in self.verdicts else {}),
                }
                for eq, r in self.equations.items()
            },
            "notes": self.notes,
            "rig": self.rig,
            "seconds": self.seconds,
        }


FIT_KEYS = ("metric", "nominal", "augmented", "verdict", "paired_t", "paired_t_log", "nominal_diverged",
            "augmented_diverged", "windows", "window_times_s", "horizon_s")


def plain(x: object) -> object:
    """Python floats/ints/lists/dicts only, with NaN and ±inf as None (strict JSON)."""
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [plain(v) for v in x]
    if isinstance(x, bool | str) or x is None:
        return x
    if isinstance(x, int | np.integer):
        return int(x)
    if isinstance(x, float | np.floating):
        return float(x) if np.isfinite(x) else None
    return x


