"""Stage: where the recording is the configured controller's own closed loop, the run re-simulated from rest with the
nominal and with the augmented model (furuta_rt.diagnose.judgement.verify), beside the recording's statistics."""

from __future__ import annotations

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.judgement import verify
from furuta_rt.diagnose.stages.findings import Found, Options, effects_of
from furuta_rt.diagnose.stages.state import State
from furuta_rt.model.effects import Effects
from furuta_rt.recording import Recording


def stage(s: State) -> State:
    if not s.opts.closed_loop:
        return s
    stats, note = resimulation(s.rec, s.rig, list(s.found), s.opts)
    s = s.with_(closed_loop=stats)
    return s.noted(note) if note else s


def resimulation(rec: Recording, rig: RigConfig, found: list[Found], opts: Options) -> tuple[dict | None, str]:
    """(the statistics of the recording, its nominal and its augmented re-simulation; or None and why not)."""
    why = moving_start(rec) if rec.meta.get("stretch_of_log") else ""
    if why:
        return None, f"{why}; the closed-loop re-simulation starts from rest and is skipped"
    own, r2 = verify.is_own_closed_loop(rec, rig)
    if not own:
        return None, (f"the commands are only partly the configured controller's (R² = {r2:.2f}); no closed-loop "
                      "re-simulation" if r2 > 0.5 else "")
    data = verify.closed_loop_stats(rec)
    nominal = verify.closed_loop_stats(verify.resimulate(rec, rig, Effects(), opts.seed, opts.substep_hz))
    try:
        eff = effects_of(found)
    except ValueError:
        return {"data": data, "nominal": nominal, "augmented": None, "replay_r2": r2}, ""
    augmented = verify.closed_loop_stats(verify.resimulate(rec, rig, eff, opts.seed, opts.substep_hz)) if found else nominal
    return {"data": data, "nominal": nominal, "augmented": augmented, "replay_r2": r2}, ""


def moving_start(rec: Recording) -> str:
    """Why a stretch cut out of a log does not start as a run does (at rest near upright with the arm near its zero),
    or '' when it does: a balancing stretch after a swing-up's catch starts with the pendulum and the arm moving and
    the arm turns away from zero, which a closed-loop re-simulation from rest (verify.resimulate) cannot reproduce."""
    k = min(len(rec) - 1, 10)
    if k < 2:
        return ""
    span = float(rec.t[k] - rec.t[0])
    phi_dot = abs(float(rec.phi[k] - rec.phi[0])) / span
    theta_dot = abs(float(rec.theta[k] - rec.theta[0])) / span
    if phi_dot > START_REST or theta_dot > START_REST or abs(float(rec.phi[0])) > START_PHI:
        return (f"the balancing stretch starts moving (φ = {float(rec.phi[0]):+.2f} rad, |φ̇| ≈ {phi_dot:.2f} rad/s, "
                f"|θ̇| ≈ {theta_dot:.2f} rad/s: after a swing-up's catch)")
    return ""


START_REST = 0.5  # rad/s: a stretch starting faster than this is not at rest
START_PHI = 1.0  # rad: ... or with the arm this far from its zero
