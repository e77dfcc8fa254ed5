"""A recording with gaps (dropped samples, a logger pause, missing rows, a time column that jumps) diagnosed as the
stretches between them.

A gap is a step between consecutive complete rows (t, θ, φ, u and θ̇ when logged all finite) longer than
GAP_PERIODS median sample periods: a time column that jumps by three or more samples, or three or more rows with a
missing value (half a period of margin keeps a jittery clock's two missing samples inside). Shorter holes stay inside a
stretch and are filled by prepare() as before. Each stretch is prepared on its own (its grid,
its derivatives, its filter edges and its time blocks), so nothing is differentiated or smoothed across a gap; a
stretch too short for the widest kernel (regression.states.long_enough) is dropped and counted. The equations are
then fitted on the rows of all stretches together by the joint fit's machinery (furuta_rt.diagnose.joint.joint_fit:
the held-out blocks stay within one stretch), with the arm spring's constant shared — one recording has one encoder
zero. One usable stretch is diagnosed alone by the whole pipeline.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.engine import Diagnosis, diagnose, plain
from furuta_rt.diagnose.joint import context, effect_line, joint_fit
from furuta_rt.diagnose.regression.library import ARM, PEND
from furuta_rt.diagnose.regression.states import MIN_SECONDS, long_enough
from furuta_rt.diagnose.stages import conventions
from furuta_rt.diagnose.stages.findings import Found, Options
from furuta_rt.errors import UserError
from furuta_rt.recording import Recording

GAP_PERIODS = 3.5  # a step between complete rows longer than this many median periods is a gap


@dataclass(frozen=True)
class Split:
    """A recording cut at its gaps: the stretches long enough to diagnose, and what was lost."""

    segments: tuple[Recording, ...]
    gaps: int
    dropped: int  # stretches too short for the filter
    lost_s: float  # time in the gaps and in the dropped stretches
    total_s: float

    def line(self) -> str:
        """The one line the report gives."""
        return (f"{self.gaps} gap(s) in the recording (3 or more samples missing): "
                f"{len(self.segments)} segment(s) diagnosed, {self.dropped} too short for the filter dropped, "
                f"{self.lost_s:.2f} s of {self.total_s:.2f} s lost")

    def spans(self) -> list[str]:
        return [f"t = {s.t[0]:.2f}–{s.t[-1]:.2f} s" for s in self.segments]


def _columns(rec: Recording) -> list[np.ndarray]:
    cols = [rec.t, rec.theta, rec.phi, rec.u] + ([rec.theta_dot] if rec.theta_dot is not None else [])
    return [np.asarray(c, dtype=float) for c in cols]


def split_at_gaps(rec: Recording) -> Split:
    """``rec`` cut at its gaps (see the module docstring); one segment, itself, when it has none."""
    cols = _columns(rec)
    complete = np.flatnonzero(np.all([np.isfinite(c) for c in cols], axis=0))
    if len(complete) < 2:
        raise UserError(f"the recording has {len(complete)} complete row(s) (t, theta, phi, u all finite) of "
                        f"{len(rec.t)}: nothing to diagnose")
    t = cols[0][complete]
    steps = np.diff(t)
    dt = float(np.median(steps))
    if not dt > 0:
        return Split((rec,), 0, 0, 0.0, float(t[-1] - t[0]))  # prepare() refuses it, naming the problem
    breaks = np.flatnonzero(steps > GAP_PERIODS * dt)
    total = float(t[-1] - t[0]) + dt
    if not len(breaks):  # holes of fewer rows (and incomplete rows at the ends): prepare() fills them
        return Split((rec,), 0, 0, 0.0, total)
    firsts = np.concatenate([[0], breaks + 1])
    lasts = np.concatenate([breaks, [len(complete) - 1]])
    kept, used = [], 0.0
    for a, b in zip(firsts, lasts, strict=True):
        if long_enough(int(complete[b] - complete[a] + 1), dt):
            kept.append(rec.slice(int(complete[a]), int(complete[b]) + 1))
            used += float(t[b] - t[a]) + dt
    return Split(tuple(kept), len(breaks), len(firsts) - len(kept), total - used, total)


def refused(split: Split) -> UserError:
    return UserError(f"the recording has {split.gaps} gap(s) and no stretch between them of at least "
                     f"{MIN_SECONDS:.0f} s that the filter can use ({split.dropped} too short): nothing to diagnose")


@dataclass
class SegmentedDiagnosis:
    """What the stretches of one recording say together (the inverse-dynamics selection and look-alike tests)."""

    split: Split = field(repr=False)
    effects: list[Found]
    ambiguities: list[dict]
    lookalikes: list[dict]
    rows: dict[str, list[int]]
    notes: list[str]
    seconds: float

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.effects]

    def to_json(self) -> dict:
        s = self.split
        return plain({  # type: ignore[return-value]
            "segmented": True,
            "gaps": {"gaps": s.gaps, "segments": s.spans(), "dropped": s.dropped, "lost_s": s.lost_s,
                     "total_s": s.total_s, "line": s.line()},
            "effects": [e.as_json() for e in self.effects],
            "evidence": [{"name": e.name, "equation": e.equation, "t": e.t, "se": e.se} for e in self.effects],
            "ambiguities": self.ambiguities,
            "lookalikes": self.lookalikes,
            "rows": self.rows,
            "notes": self.notes,
            "seconds": self.seconds,
        })

    def text(self) -> list[str]:
        out = [self.split.line(), f"segments: {', '.join(self.split.spans())} (arm rows "
               f"{' + '.join(map(str, self.rows[ARM]))}, pendulum rows {' + '.join(map(str, self.rows[PEND]))})"]
        out.append("effects (fitted on all segments):" if self.effects else "effects: none (the nominal model fits)")
        out += [effect_line(e) for e in self.effects]
        out += [f"  look-alike {' ↔ '.join(a['effects'])}: {a['reason']}" for a in self.ambiguities]
        return out + [f"note: {n}" for n in self.notes]


def diagnose_segments(split: Split, rig: RigConfig, options: Options | None = None) -> SegmentedDiagnosis:
    """The stretches of ``split`` (two or more) fitted together (see the module docstring)."""
    opts = options or Options()
    t0 = time.perf_counter()
    ctxs = [context(seg, rig, opts, []) for seg in split.segments]
    notes = [*split.segments[0].meta.get("input_notes", [])]
    if opts.check_conventions:  # the signs and units, judged on the longest stretch
        notes += conventions.conventions(max(ctxs, key=lambda c: c.prep.n).prep, rig)
    found, ambiguities, lookalikes, rows = joint_fit(ctxs, opts, notes, per_member={})
    notes.append("segmented fit: the inverse-dynamics selection and look-alike tests over all segments; the window "
                 "stages, the prediction gate and the closed-loop check need one continuous recording and did not run")
    return SegmentedDiagnosis(split, found, ambiguities, lookalikes, rows, notes, time.perf_counter() - t0)


def diagnose_recording(rec: Recording, rig: RigConfig, options: Options | None = None,
                       split: Split | None = None) -> Diagnosis | SegmentedDiagnosis:
    """``rec`` diagnosed whole when it has no gap, else as its stretches: one alone (the whole pipeline, the gap
    line among its notes), several together (diagnose_segments); none long enough is a UserError."""
    split = split or split_at_gaps(rec)
    if split.gaps == 0 and len(split.segments) == 1 and split.segments[0] is rec:
        return diagnose(rec, rig, options)
    if not split.segments:
        raise refused(split)
    if len(split.segments) == 1:
        seg = split.segments[0]
        seg.meta["input_notes"] = [*seg.meta.get("input_notes", []), split.line()]
        return diagnose(seg, rig, options)
    return diagnose_segments(split, rig, options)
