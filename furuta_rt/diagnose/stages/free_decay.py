"""Stage: a recording that is a pendulum free swing (furuta_rt.diagnose.stages.swing; its decay: stages.decay) is the
experiment that tells viscous from Coulomb pivot friction: its energy-per-cycle fit replaces the pendulum friction of
the inverse-dynamics selection and settles their look-alike."""

from __future__ import annotations

from collections.abc import Mapping

from furuta_rt.diagnose.regression.library import PEND
from furuta_rt.diagnose.stages import swing
from furuta_rt.diagnose.stages.decay import DecayFit, free_decay
from furuta_rt.diagnose.stages.findings import Found
from furuta_rt.diagnose.stages.lookalikes import EXPERIMENTS
from furuta_rt.diagnose.stages.state import State


def stage(s: State) -> State:
    prep, rig = s.ctx.prep, s.rig
    if not swing.is_free_swing(prep, rig):
        return s
    decay = free_decay(prep, rig)
    if decay is None:
        return s.noted(swing.TOO_FEW)
    f = {k: v.loo_rms for k, v in decay.fits.items()}
    pend = [e for e in _decay_effects(decay.fits[decay.best]) if not _as_known(e, s.ctx.known)]
    read = swing.read(prep, rig, decay.peaks_t, decay.rest_offset, lossless=decay.best == "none")
    return s.with_(
        decay=decay, decay_report={**decay.as_json(), **read.as_json()},
        found=[e for e in s.found if e.name not in PENDULUM_FRICTION] + pend,
        ambiguities=[a for a in s.ambiguities if not set(a["effects"]) <= set(PENDULUM_FRICTION)],
        lookalikes=[*s.lookalikes, {
            "effects": list(PENDULUM_FRICTION), "reported": ", ".join(e.name for e in pend) or "none",
            "reason": f"the recording is a free decay of {decay.cycles} cycles: " + (
                "it loses no measurable energy per cycle (its losses and gains balance within their scatter)"
                if decay.best == "none" else
                f"the energy lost per cycle is predicted within {100 * f['both']:.0f} % by viscous + Coulomb, "
                f"{100 * f['viscous']:.0f} % by viscous alone, {100 * f['coulomb']:.0f} % by Coulomb alone "
                "(leave-one-cycle-out)"),
            "experiment": EXPERIMENTS[frozenset(PENDULUM_FRICTION)],
        }],
    ).noted(*read.notes())


PENDULUM_FRICTION = ("pendulum_viscous", "pendulum_coulomb")


def _decay_effects(fit: DecayFit) -> list[Found]:
    out = []
    if fit.bp > 0:
        out.append(Found("pendulum_viscous", PEND, {"bp": fit.bp}, {"bp": fit.se_bp}, fit.bp / (fit.se_bp or 1.0), 0.0,
                         "free decay"))
    if fit.Fc > 0:
        out.append(Found("pendulum_coulomb", PEND, {"Fc": fit.Fc}, {"Fc": fit.se_Fc}, fit.Fc / (fit.se_Fc or 1.0), 0.0,
                         "free decay"))
    return out


def _as_known(e: Found, known: Mapping[str, Mapping[str, float]]) -> bool:
    """Whether a found effect is the rig's own, at its configured value (within two standard errors)."""
    if e.name not in known:
        return False
    return all(abs(v - known[e.name].get(k, 0.0)) <= 2 * e.se.get(k, 0.0) for k, v in e.params.items())
