"""`diagnose a.mcap b.mcap …`: the rig's properties fitted jointly across several recordings of one rig.

One recording may not separate two look-alikes (an input gain and an arm inertia on balancing alone, a spring and an
inertia on one sine, a dead band and dry friction at one speed); a designed experiment's recording adds the rows that
do. The joint fit stacks the recordings' inverse-dynamics rows (each recording keeps its own states, kernels and
time blocks) and runs diagnose's own selection (stages.equations.select_in: forward selection, refit, the significance
and backward passes; not the latency stage, which reads one recording's time line) and its own look-alike judgement
(stages.lookalikes.check_lookalikes: the paired t of the held-out block errors, the κ test for gain ↔ inertia, the rest
test for a bias; stages.lookalikes.swapped where the look-alike wins) on the stack. The physical parameters are shared;
a nuisance term that belongs to a run, not to the rig, gets one column per recording: the arm encoder's zero is set
when a run starts, so a cable spring's −k(φ − φ0) has its constant k·φ0 per recording. A recording with gaps
(furuta_rt.diagnose.segments: a busy machine's dropped samples) takes part as the stretches between them, each
prepared alone, the per-recording column shared by its stretches.

Each recording is also diagnosed alone (the whole pipeline), and every look-alike a single recording left
unresolved is reported with what the joint fit made of it: resolved (which one, the test that decided), none of the
two (the joint model needs neither), or still unresolved with the data the next plan needs — the paired t and the κ
test grow as the square root of the rows added, so the length that lifts them over their thresholds follows from
the joint values.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.engine import Diagnosis, plain
from furuta_rt.diagnose.regression.fitting import Blocks
from furuta_rt.diagnose.regression.library import ARM, PEND, Context, InputPath
from furuta_rt.diagnose.regression.selection import EquationModel, Spec
from furuta_rt.diagnose.regression.states import prepare
from furuta_rt.diagnose.stages.equations import fair_baseline, select_in
from furuta_rt.diagnose.stages.findings import EquationResult, Found, Options, found_in, refit
from furuta_rt.diagnose.stages.lookalikes import SEPARATION_Z, check_lookalikes, gain_inertia_separation, swapped
from furuta_rt.diagnose.stages.start import arm_sigma, balancing_span
from furuta_rt.errors import UserError
from furuta_rt.recording import Recording

PER_RECORDING: dict[str, tuple[int, ...]] = {"arm_spring": (1,)}  # effect: its columns that belong to a run
"""The arm_spring columns are (−φ, 1): the constant k·φ0 moves with the encoder zero each run sets."""


class JointPrep:
    """The members' Prepared recordings end to end: the arrays the selection reads (command, validity, arm angle, time)
    concatenated, the sampling constants shared (checked equal)."""

    def __init__(self, parts: list[Any]) -> None:
        self.parts = parts
        first = parts[0]
        for p in parts[1:]:
            if abs(p.dt - first.dt) > 1e-9 * first.dt or abs(p.command_lag - first.command_lag) > 1e-12:
                raise UserError("the recordings were not made at one rate and command delay: a joint fit needs one rig")
        self.dt, self.command_lag, self.phi_lsb = first.dt, first.command_lag, first.phi_lsb
        self.u = np.concatenate([p.u for p in parts])
        self.valid = np.concatenate([p.valid for p in parts])
        self.phi = np.concatenate([p.phi for p in parts])
        self.t = np.concatenate([p.t for p in parts])

    @property
    def n(self) -> int:
        return len(self.u)

    @property
    def commanded(self) -> bool:
        return any(p.commanded for p in self.parts)


class JointContext:
    """The members' Contexts as one: per-row arrays concatenated, the rig's constants from the first (one rig)."""

    SHARED = ("rig", "model", "plant", "also_search", "known", "known_value", "known_gain", "base_path", "base_inertia",
              "back_emf", "lugre_params")

    def __init__(self, parts: list[Context]) -> None:
        self.parts = parts
        self.prep = JointPrep([c.prep for c in parts])

    def __getattr__(self, name: str) -> Any:
        if name in JointContext.SHARED:
            return getattr(self.parts[0], name)
        raise AttributeError(f"the joint fit has no {name!r} (a per-recording quantity it does not stack)")

    def _cat(self, get: Any) -> np.ndarray:
        return np.concatenate([np.broadcast_to(get(c), (c.prep.n,)) for c in self.parts])

    @property
    def arm_travel(self) -> tuple[float, float]:
        return min(c.arm_travel[0] for c in self.parts), max(c.arm_travel[1] for c in self.parts)

    @property
    def arm_dJ(self) -> np.ndarray:
        return self._cat(lambda c: c.arm_dJ)

    @property
    def arm_m22(self) -> np.ndarray:
        return self._cat(lambda c: c.arm_m22)

    @property
    def arm_pendulum_part(self) -> np.ndarray:
        return self._cat(lambda c: c.arm_pendulum_part)

    def arm_weight(self, d_inertia: float) -> np.ndarray | float:
        return 1.0 if not d_inertia else self._cat(lambda c: c.arm_weight(d_inertia))

    def command_torque(self, path: InputPath, equation: str = ARM) -> np.ndarray:
        return self._cat(lambda c: c.command_torque(path, equation))


class JointEquationModel(EquationModel):
    """One equation of eq. 4 over several recordings: rows stacked, each recording's time blocks kept (the
    held-out blocks never span two recordings), columns shared but for PER_RECORDING ones."""

    def __init__(self, members: list[EquationModel], per_member: dict[str, tuple[int, ...]] | None = None,
                 groups: list[int] | None = None) -> None:
        self.members = members
        self.per_member = per_member  # None: PER_RECORDING; {} for segments of one recording (one encoder zero)
        self.groups = groups or list(range(len(members)))  # the recording each member (a stretch of it) belongs to
        self.ctx = JointContext([m.ctx for m in members])  # type: ignore[assignment]
        self.equation = members[0].equation
        self.th = members[0].th
        rows, bounds, offset = [], [], 0
        self.offsets = []
        for m in members:
            self.offsets.append(offset)
            base = sum(len(r) for r in rows)
            rows.append(m.blocks.rows + offset)
            bounds += [(a + base, b + base) for a, b in m.blocks.bounds]
            offset += m.ctx.prep.n
        self.blocks = Blocks(np.concatenate(rows), tuple(bounds))
        self.n_rows = len(self.blocks.rows)
        self.corr_len = max(m.corr_len for m in members)
        self._step_evals = {}
        self._trace = []

    def target(self, spec: Spec) -> np.ndarray:
        return np.concatenate([m.target(spec) for m in self.members])

    def design(self, spec: Spec) -> tuple[np.ndarray, list[tuple[str, slice]]]:
        """The members' columns stacked; a PER_RECORDING column is the first recording's in place (its owner's slice
        unchanged) and one more column per further recording at the end, zero outside that recording's members."""
        parts = [m.design(spec) for m in self.members]
        X = np.concatenate([p[0] for p in parts], axis=0)
        owners = parts[0][1]
        extra = []
        for name, sl in owners:
            for j in (PER_RECORDING if self.per_member is None else self.per_member).get(name, ()):
                col = sl.start + j
                for g in sorted(set(self.groups) - {self.groups[0]}):
                    own = np.zeros(X.shape[0])
                    for i in (i for i, gi in enumerate(self.groups) if gi == g):
                        a, b = self.offsets[i], self.offsets[i] + self.members[i].ctx.prep.n
                        own[a:b] = X[a:b, col]
                        X[a:b, col] = 0.0
                    extra.append(own)
        if extra:
            X = np.column_stack([X, *extra])
        return X, owners


@dataclass
class JointDiagnosis:
    """What the recordings say together, and what each said alone."""

    sources: list[str]
    effects: list[Found]
    ambiguities: list[dict]  # unresolved on the joint fit (stages.lookalikes.check_lookalikes), with the data still needed
    lookalikes: list[dict]  # told apart on the joint fit
    pairs: list[dict]  # each look-alike a single recording left unresolved: what the joint fit made of it
    singles: list[Diagnosis] = field(repr=False)
    rows: dict[str, list[int]] = field(default_factory=dict)  # per equation, the rows each recording gave
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.effects]

    def changes(self) -> list[dict]:
        """Per recording, the effects it named alone that the joint fit does not, and the joint fit's it did not."""
        joint = set(self.names)
        out = []
        for source, d in zip(self.sources, self.singles, strict=True):
            alone = set(d.names)
            if alone != joint:
                out.append({"recording": source, "alone_only": sorted(alone - joint), "joint_only": sorted(joint - alone)})
        return out

    def to_json(self) -> dict:
        return plain({  # type: ignore[return-value]
            "joint": True,
            "recordings": self.sources,
            "effects": [e.as_json() for e in self.effects],
            "ambiguities": self.ambiguities,
            "lookalikes": self.lookalikes,
            "pairs": self.pairs,
            "changes": self.changes(),
            "rows": self.rows,
            "single": [{"recording": s, "effects": [e.as_json() for e in d.effects], "ambiguities": d.ambiguities}
                       for s, d in zip(self.sources, self.singles, strict=True)],
            "notes": self.notes,
            "seconds": self.seconds,
        })


def context(rec: Recording, rig: RigConfig, opts: Options, notes: list[str]) -> Context:
    """A recording's Context as diagnose builds it (its longest balancing stretch, its own arm kernel)."""
    rec = balancing_span(rec, notes)
    prep = prepare(rec, rig)
    return Context.build(prep, rig, opts.sigma_arm or arm_sigma(prep), opts.sigma_pend, opts.sigma_fine,
                         frozenset(opts.also_search))


def needed_factor(entry: dict, opts: Options) -> float:
    """How many times the joint rows an unresolved pair needs to clear a test that could decide it (both grow as the
    square root of the rows; the smaller factor): the paired t to ``ambiguity_t``, when the held-out errors already
    differ by ``ambiguity_gain`` (a relative difference does not grow with the data), and, for gain ↔ inertia, κ's
    separation to SEPARATION_Z standard errors. Infinite when neither can."""
    out = []
    t = abs(float(entry.get("paired_t") or 0.0))
    if t > 0 and abs(float(entry.get("cv_difference") or 0.0)) >= opts.ambiguity_gain:
        out.append((opts.ambiguity_t / t) ** 2)
    sep = entry.get("separation")
    if sep and sep.get("se") and sep.get("predicted_alternative"):
        # the two predictions SEPARATION_Z errors apart, and κ as far from the one it rejects (as measured so far)
        gap = min(abs(sep["predicted_alternative"]), max(abs(sep["kappa"]), abs(sep["kappa"] - sep["predicted_alternative"])))
        out.append((SEPARATION_Z * sep["se"] / gap) ** 2)
    return min(out) if out else float("inf")


def joint_fit(ctxs: list[Context], opts: Options, notes: list[str], per_member: dict[str, tuple[int, ...]] | None = None,
              groups: list[int] | None = None) -> tuple[list[Found], list[dict], list[dict], dict[str, list[int]]]:
    """Each equation's selection and the look-alike tests on the members' rows stacked (JointEquationModel): the
    effects found, the look-alikes left unresolved and told apart, and per equation the rows each member gave (each
    recording's, its stretches added, with ``groups``: the recording each member is a stretch of)."""
    ems: dict[str, JointEquationModel] = {}
    res: dict[str, EquationResult] = {}
    rows: dict[str, list[int]] = {}
    for eq in (ARM, PEND):
        members = [EquationModel(c, eq, opts.thresholds) for c in ctxs]
        ems[eq] = JointEquationModel(members, per_member, groups)
        by = groups or list(range(len(members)))
        rows[eq] = [sum(m.n_rows for m, g in zip(members, by, strict=True) if g == k) for k in sorted(set(by))]
        res[eq] = select_in(ems[eq], settle_latency=False)
    ambiguities, lookalikes, swaps = check_lookalikes(ems, res, opts)  # type: ignore[arg-type]
    for eq, alt in swaps.items():  # the look-alike test favours the alternative: it becomes the equation's model
        res[eq] = swapped(ems[eq], res[eq], alt)
    found = [f for eq in (ARM, PEND) for f in found_in(ems[eq], res[eq], notes)]
    return found, ambiguities, lookalikes, rows


def effect_line(e: Found) -> str:
    """One found effect as a line of text: its parameters ± their standard errors."""
    params = ", ".join(f"{k} = {v:.4g} ± {e.se.get(k, float('nan')):.2g}" for k, v in e.params.items())
    return f"  {e.name}: {params} (t = {e.t:.1f}, {e.equation} equation)"


def pair_test(em: EquationModel, truth: str, rival: str, base: Spec | None = None) -> dict:
    """diagnose's look-alike statistics for one pair on ``em`` (one recording's equation, or a JointEquationModel),
    with ``truth`` the model named and ``rival`` in its place on top of ``base`` (default the nominal model): the
    paired t of the held-out block errors (rival against truth, the truth's nonlinear parameter re-profiled in each
    fold as stages.equations.fair_baseline does: positive when the data favour ``truth``), the relative held-out difference, and
    for gain ↔ inertia the κ test (stages.lookalikes.gain_inertia_separation) with z = |κ − the rival's prediction| / se, the
    standard errors by which the data reject the rival. ``decisive``: the statistic that decides this pair (κ's z for
    gain ↔ inertia, else the paired t) and ``threshold`` the value it must reach."""
    from furuta_rt.diagnose.regression.fitting import paired_t

    base = base or em.spec0()
    out: dict[str, Any] = {"truth": truth, "rival": rival, "paired_t": 0.0, "cv_difference": 0.0, "decisive": 0.0,
                           "threshold": Options().ambiguity_t, "test": "paired t", "rows": em.n_rows}
    if {truth, rival} == {"input_gain", "arm_inertia"}:
        out.update(threshold=SEPARATION_Z, test="κ z")
    if em.n_rows < 20 * em.th.n_blocks:  # too few rows to fit either (the arm hardly moves): nothing separates them
        return out
    named = refit(em, base.with_effect(truth))
    fair = fair_baseline(em, named, truth)
    alt = em.evaluate_with(base, rival)
    t = paired_t(alt.fit.cv_block, fair.fit.cv_block)
    rel = (alt.cv - fair.cv) / fair.cv if fair.cv else 0.0
    out.update(paired_t=float(t), cv_difference=float(rel), decisive=float(t))
    if {truth, rival} == {"input_gain", "arm_inertia"}:
        gain = (named if truth == "input_gain" else alt).params["input_gain"]["gain"]
        sep = gain_inertia_separation(em, named, gain, truth == "input_gain")
        z = abs(sep["kappa"] - sep["predicted_alternative"]) / sep["se"]
        out.update(kappa=sep["kappa"], se=sep["se"], predicted_alternative=sep["predicted_alternative"], kappa_z=z,
                   decisive=float(z))
    return out
