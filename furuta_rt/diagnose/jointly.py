"""`diagnose a.mcap b.mcap …`: several recordings of one rig diagnosed jointly — each alone (with its gaps split,
furuta_rt.diagnose.segments) and all together by the joint fit (furuta_rt.diagnose.joint, whose module docstring
says how), with every look-alike a single recording left unresolved answered."""

from __future__ import annotations

import time

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.engine import Diagnosis
from furuta_rt.diagnose.joint import JointDiagnosis, context, effect_line, joint_fit, needed_factor
from furuta_rt.diagnose.regression.library import ARM, PEND
from furuta_rt.diagnose.segments import diagnose_recording, refused, split_at_gaps
from furuta_rt.diagnose.stages.findings import Found, Options
from furuta_rt.errors import UserError
from furuta_rt.recording import Recording


def diagnose_joint(recordings: list[tuple[str, Recording]], rig: RigConfig, options: Options | None = None,
                   singles: list[Diagnosis] | None = None) -> JointDiagnosis:
    """Diagnose ``recordings`` (name, recording) of one rig jointly (see the module docstring). ``singles``: their
    single diagnoses if already made (same order)."""
    if len(recordings) < 2:
        raise UserError("a joint diagnosis needs two or more recordings")

    opts = options or Options()
    t0 = time.perf_counter()
    notes: list[str] = []
    splits = [split_at_gaps(rec) for _, rec in recordings]
    for (name, _), split in zip(recordings, splits, strict=True):
        if not split.segments:
            raise UserError(f"{name}: {refused(split)}")
        if split.gaps:
            notes.append(f"{name}: {split.line()}")
    singles = singles or [diagnose_recording(rec, rig, opts, split)  # type: ignore[misc]
                          for (_, rec), split in zip(recordings, splits, strict=True)]
    ctxs = [context(seg, rig, opts, []) for split in splits for seg in split.segments]
    groups = [k for k, split in enumerate(splits) for _ in split.segments]
    found, ambiguities, lookalikes, rows = joint_fit(ctxs, opts, notes, groups=groups)
    total_s = sum(c.prep.n * c.prep.dt for c in ctxs)
    for a in ambiguities:
        factor = needed_factor(a, opts)
        a["more_data_factor"] = factor
        a["more_seconds"] = max(factor - 1.0, 0.0) * total_s if np.isfinite(factor) else None
    notes.append("joint fit: the inverse-dynamics selection and look-alike tests over all recordings; the window stages "
                 "(sticks, command peaks), the prediction gate and the closed-loop check run per recording (single)")
    pairs = _pairs(singles, [name for name, _ in recordings], found, ambiguities, lookalikes)
    return JointDiagnosis([name for name, _ in recordings], found, ambiguities, lookalikes, pairs, singles, rows, notes,
                          time.perf_counter() - t0)


def _pairs(singles: list[Diagnosis], names: list[str], found: list[Found], ambiguities: list[dict],
           lookalikes: list[dict]) -> list[dict]:
    """Each look-alike pair some recording alone left unresolved, with the joint fit's answer."""
    seen: dict[frozenset[str], dict] = {}
    for name, d in zip(names, singles, strict=True):
        for a in d.ambiguities:
            key = frozenset(a["effects"])
            entry = seen.setdefault(key, {"effects": list(a["effects"]), "single": []})
            entry["single"].append({"recording": name, "reported": a["reported"], "paired_t": a.get("paired_t")})
    have = {f.name for f in found}
    for key, entry in seen.items():
        amb = next((a for a in ambiguities if frozenset(a["effects"]) == key), None)
        apart = next((a for a in lookalikes if frozenset(a["effects"]) == key), None)
        if amb is not None:
            entry.update(status="unresolved", reported=amb["reported"], paired_t=amb.get("paired_t"),
                         reason=amb["reason"], more_seconds=amb.get("more_seconds"),
                         more_data_factor=amb.get("more_data_factor"))
        elif apart is not None:
            entry.update(status="resolved", reported=apart["reported"], reason=apart["reason"])
        elif not key & have:
            entry.update(status="resolved", reported="none",
                         reason="the joint fit selects neither: the recordings together ask for none of the two")
        else:
            entry.update(status="resolved", reported=" + ".join(sorted(key & have)),
                         reason="the joint fit selects " + " and ".join(sorted(key & have)) + (
                             "" if key <= have else f"; {', '.join(sorted(key - have))} is not selected"))
    return list(seen.values())


def text(j: JointDiagnosis) -> list[str]:
    """The joint diagnosis as lines of text."""
    out = [f"joint diagnosis of {len(j.sources)} recordings: {', '.join(j.sources)} "
           f"(arm rows {' + '.join(map(str, j.rows.get(ARM, [])))}, pendulum rows "
           f"{' + '.join(map(str, j.rows.get(PEND, [])))})"]
    out.append("effects (shared by all recordings):" if j.effects else "effects: none (the nominal model fits)")
    out += [effect_line(e) for e in j.effects]
    for c in j.changes():
        parts = ([f"named {', '.join(c['alone_only'])}, which the recordings together do not ask for"] if c["alone_only"]
                 else []) + ([f"missed {', '.join(c['joint_only'])}"] if c["joint_only"] else [])
        out.append(f"  {c['recording']} alone {' and '.join(parts)}")
    if j.pairs:
        out.append("look-alikes one recording alone could not tell apart:")
    for p in j.pairs:
        before = "; ".join(f"{s['recording']}: {s['reported']}, paired t {s['paired_t'] or 0:.1f}" for s in p["single"])
        out.append(f"  {' ↔ '.join(p['effects'])} ({before})")
        if p["status"] == "unresolved":
            more = p.get("more_seconds")
            need = (f"; about {more:.0f} s more of such data would decide it" if more is not None else
                    "; more of such data would not decide it (the held-out errors differ too little)")
            if set(p["effects"]) == {"input_gain", "arm_inertia"}:
                need += ("; a hanging experiment swings the pendulum far more than balancing can, and with it the "
                         "term that tells them apart (furuta-rt experiment design --hanging)")
            out.append(f"    still unresolved jointly: {p['reason']}{need}")
        else:
            out.append(f"    resolved jointly: {p['reported']} — {p['reason']}")
    for a in j.ambiguities:
        if not any(set(a["effects"]) == set(p["effects"]) for p in j.pairs):
            out.append(f"  joint look-alike {' ↔ '.join(a['effects'])}: {a['reason']}")
    out += [f"note: {n}" for n in j.notes]
    return out
