"""Show the fit: the nominal and the augmented model simulated against held-out data.

* Multi-step prediction: windows of the recording are re-initialised from the reconstructed state and
  simulated open loop with the recorded commands through furuta_rt.sim.simulator.Simulator (a RigModel
  of the rig plus the effects; sensor noise off). The error of the predicted θ_f (through the Bessel
  path) and φ is normalised by each signal's spread: NRMSE, averaged over θ and φ.
* Closed loop: when the commands are the rig's own controller, the whole run is re-simulated with
  furuta_rt.sim.closed_loop.run_closed_loop and its statistics (std of θ, φ, u; limit cycle of φ)
  compared with the recording's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.control.controller import Controller, Measurement
from furuta_rt.diagnose.signals import Prepared, States
from furuta_rt.model.effects import Effects
from furuta_rt.model.rig import RigModel
from furuta_rt.recording import Recording
from furuta_rt.sim.closed_loop import run_closed_loop
from furuta_rt.sim.simulator import Simulator
from furuta_rt.stats import summary_stats

PREDICTION_METRIC = "multi-step prediction NRMSE, mean of θ and φ, on held-out windows"


def quiet(rig: RigConfig) -> RigConfig:
    """The rig without sensor noise (simulations here are predictions, not synthetic data)."""
    return rig.model_copy(update={"sensors": rig.sensors.model_copy(update={"theta_noise": 0.0, "theta_dot_noise": 0.0})})


def start_simulator(model: RigModel, prep: Prepared, fine: States, k: int, rate: float, substep_hz: float,
                    phi_dot: float | None = None) -> Simulator:
    """A Simulator in the reconstructed state of sample k, its filter and delay line primed from the data;
    ``phi_dot``: the arm's starting velocity instead of the reconstructed one (0: at rest, so a friction law with a
    stick limit holds it)."""
    v = float(fine.phi_dot[k]) if phi_dot is None else phi_dot
    x0 = (float(fine.theta[k] - model.theta_offset), float(fine.theta_dot[k]), float(prep.phi[k]), v)
    sim = Simulator(model, rate, substep_hz, seed=0, x0=x0)
    if model.bessel is not None:  # the analog filter's own state: the measured θ_f, θ̇_f (lightly smoothed)
        sim.y = float(fine.smooth(prep.theta_f)[k])
        sim.y_dot = float(fine.smooth(prep.theta_dot_f)[k]) if prep.theta_dot_f is not None else float(fine.theta_dot[k])
    n = len(sim.commands_in_flight)  # the actuator's transport delay: fill with the commands already in flight
    if n:
        D = 0 if sim.commands_at_sample else round(prep.command_lag / prep.dt)
        queued = []
        for i in range(n):
            t_sub = -(n - i) * sim.h  # time before t_k of this queued substep command
            j = k + int(np.floor(t_sub / prep.dt)) - D
            queued.append(float(prep.u[max(j, 0)]))
        sim.set_commands_in_flight(queued)
    return sim


@dataclass(frozen=True)
class Prediction:
    nrmse_theta: float
    nrmse_phi: float
    windows: int

    @property
    def nrmse(self) -> float:
        """Mean over θ and φ (θ alone when the arm does not move)."""
        return float(np.nanmean([self.nrmse_theta, self.nrmse_phi]))


def window_starts(prep: Prepared, start: int, stop: int, horizon: int, spacing: int) -> list[int]:
    lo = max(start, int(np.argmax(prep.valid)))
    hi = min(stop, len(prep.t) - horizon - 1)
    return list(range(lo, hi, spacing))


def simulate_window(model: RigModel, prep: Prepared, fine: States, k: int, horizon: int,
                    substep_hz: float = 2000.0) -> tuple[np.ndarray, np.ndarray]:
    """(θ_f, φ) predicted for ticks k+1 … k+horizon, open loop with the recorded commands."""
    sim = start_simulator(model, prep, fine, k, 1.0 / prep.dt, substep_hz)
    D = 0 if sim.commands_at_sample else round(prep.command_lag / prep.dt)  # command_latency: the line lags
    th = np.empty(horizon)
    ph = np.empty(horizon)
    for j in range(horizon):
        sim.set_command(float(prep.u[max(k + j - D, 0)]))
        sim.advance(1)
        th[j] = sim.filtered_theta()[0]
        ph[j] = sim.phi
    return th, ph


def predict(rig: RigConfig, effects: Effects, prep: Prepared, fine: States, starts: list[int], horizon: int,
            substep_hz: float = 2000.0) -> Prediction:
    """Open-loop multi-step prediction of θ_f and φ over ``horizon`` ticks from each start."""
    if not starts:
        return Prediction(float("nan"), float("nan"), 0)
    model = RigModel.from_config(quiet(rig), effects)
    e_th, e_ph = [], []
    for k in starts:
        th, ph = simulate_window(model, prep, fine, k, horizon, substep_hz)
        e_th.append(th - prep.theta_f[k + 1 : k + 1 + horizon])
        e_ph.append(ph - prep.phi[k + 1 : k + 1 + horizon])
    v = prep.valid
    s_th = float(np.std(prep.theta_f[v])) or 1.0
    s_ph = float(np.std(prep.phi[v])) or 1.0
    nrmse_phi = _rms(e_ph) / s_ph if prep.moves(prep.phi) else float("nan")  # an arm that stays put is no test
    return Prediction(_rms(e_th) / s_th, nrmse_phi, len(starts))


def _rms(parts: list[np.ndarray]) -> float:
    return float(np.sqrt(np.mean(np.concatenate(parts) ** 2)))


# ---------------------------------------------------------------------------------- closed loop
def replay_commands(rec: Recording, rig: RigConfig) -> np.ndarray:
    """The commands the rig's configured controller computes from the recorded measurements."""
    ctrl = Controller.from_rig(rig, mode=str(rec.meta["mode"]) if rec.meta.get("mode") else None)  # type: ignore[arg-type]
    ref = rec.extra.get("phi_ref")
    td = rec.theta_dot if rec.theta_dot is not None else np.gradient(rec.theta, rec.t)
    out = np.empty(len(rec))
    for k in range(len(rec)):
        phi = float(rec.phi[k] - (ref[k] if ref is not None else 0.0))
        out[k] = ctrl.update(Measurement(float(rec.t[k]), float(rec.theta[k]), float(td[k]), phi)).u
    return out


def is_own_closed_loop(rec: Recording, rig: RigConfig) -> tuple[bool, float]:
    """(the recording's u is the configured controller's, R² of the replayed commands)."""
    u = np.asarray(rec.u, float)
    if np.std(u) == 0:
        return False, 0.0
    try:
        uh = replay_commands(rec, rig)
    except (ValueError, KeyError):
        return False, 0.0
    r2 = 1.0 - float(np.var(u - uh) / np.var(u))
    return r2 > 0.95, r2


def closed_loop_stats(rec: Recording) -> dict[str, float | None]:
    """std of θ, φ, u and the φ limit cycle (amplitude, period) of a recording (furuta_rt.stats)."""
    s = summary_stats(rec, start=float(rec.t[0]) + min(5.0, 0.2 * (rec.t[-1] - rec.t[0])))
    lc = s.get("limit_cycle_phi")
    return {
        "std_theta": s["theta"]["std"], "std_phi": s["phi"]["std"], "std_u": s["u"]["std"],
        "lc_phi_amplitude": lc["amplitude"] if lc else None, "lc_phi_period": lc["period"] if lc else None,
    }


def resimulate(rec: Recording, rig: RigConfig, effects: Effects, seed: int = 0, substep_hz: float = 2000.0) -> Recording:
    """The recording's run re-simulated in closed loop with ``effects`` (same start, reference, duration)."""
    n = len(rec)
    dur = n / rig.control.rate_hz
    x0 = (float(rec.theta[0]), 0.0, float(rec.phi[0]), 0.0)
    return run_closed_loop(
        rig, dur, effects=effects, seed=seed, x0=x0, substep_hz=substep_hz, reference=rec.extra.get("phi_ref"),
        mode=str(rec.meta["mode"]) if rec.meta.get("mode") else None,  # type: ignore[arg-type]
    )
