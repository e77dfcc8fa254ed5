"""Show the fit: the nominal and the augmented model simulated against held-out data.

* Multi-step prediction: windows of the recording are re-initialised from the reconstructed state and
  simulated open loop with the recorded commands through furuta_rt.sim.simulator.Simulator (a RigModel
  of the rig plus the effects; sensor noise off). The windows are the informative ones (the arm moving,
  the command varying or the pendulum moving), spread over the whole recording; the horizon is a few
  e-folding times of the unstable pole of eq. 6 (an open-loop prediction of an unstable plant grows its
  error as e^{λt}); a window whose prediction leaves the data by more than the linear region (θ error
  above THETA_DIVERGED, φ error above PHI_DIVERGED, or non-finite) has diverged. Per window: the rms error
  of θ_f (through the Bessel path) and of φ, each normalised by the signal's spread over the windows
  (NRMSE), averaged over θ and φ; two models are compared by a paired t over windows.
* Closed loop: when the commands are the rig's own controller, the whole run is re-simulated with
  furuta_rt.sim.closed_loop.run_closed_loop and its statistics (std of θ, φ, u; limit cycle of φ)
  compared with the recording's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.controller.controller import Controller, Measurement
from furuta_rt.diagnose.regression.fitting import paired_t
from furuta_rt.diagnose.regression.states import Prepared, States
from furuta_rt.model.effects import Effects
from furuta_rt.model.rig import RigModel
from furuta_rt.recording import Recording
from furuta_rt.sim.closed_loop import run_closed_loop
from furuta_rt.sim.compiled import fast_simulator
from furuta_rt.sim.simulator import Simulator
from furuta_rt.stats import summary_stats

PREDICTION_METRIC = ("multi-step prediction NRMSE, mean of θ and φ, on informative windows spread over the recording, "
                     "each predicted with parameters fitted away from it (blocked cross-validation)")
THETA_DIVERGED = 0.5  # rad: a θ prediction this far from the data has left the linear region of eq. 6
PHI_DIVERGED = 1.0  # rad: an arm prediction this far off over a fraction of a second predicts nothing
E_FOLDS = 1.5  # horizon in e-folding times of the unstable pole of eq. 6 ...
HORIZON_BOUNDS = (0.1, 0.5)  # s, ... within these bounds
INFORMATIVE_SHARE = 0.1  # a window is informative when an activity reaches this share of its high percentile ...
INFORMATIVE_PERCENTILE = 95  # ... over the recording's windows
T_DIFFERENT = 2.0  # paired t over windows at which two models' predictions are called different


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
    sim = fast_simulator(model, rate, substep_hz, seed=0, x0=x0)  # compiled where it can be: the same trajectory
    if model.bessel is not None:  # the analog filter's own state: the measured θ_f, θ̇_f (lightly smoothed)
        sim.y = float(fine.smooth(prep.theta_f)[k])
        sim.y_dot = float(fine.smooth(prep.theta_dot_f)[k]) if prep.theta_dot_f is not None else float(fine.theta_dot[k])
    n = len(sim.commands_in_flight)  # the actuator's transport delay: fill with the commands already in flight
    if n:
        D, _ = model.command_timing(round(prep.command_lag / prep.dt))  # the driver's ticks of the rule
        queued = []
        for i in range(n):
            t_sub = -(n - i) * sim.h  # time before t_k of this queued substep command
            j = k + int(np.floor(t_sub / prep.dt)) - D
            queued.append(float(prep.u[max(j, 0)]))
        sim.set_commands_in_flight(queued)
    return sim


def unstable_pole(rig: RigConfig) -> float:
    """λ (1/s): the largest real part among the eigenvalues of eq. 6's A (FurutaPlant.linearize) for the rig."""
    A, _ = RigModel.from_config(rig).plant.linearize()
    return float(np.max(np.linalg.eigvals(A).real))


def horizon_ticks(rig: RigConfig, dt: float) -> int:
    """Prediction horizon: E_FOLDS e-folding times 1/λ of the unstable pole, within HORIZON_BOUNDS (an open-loop
    prediction of an unstable plant multiplies a start-state error by e^{λt}; longer windows measure that growth,
    not the model)."""
    lam = unstable_pole(rig)
    seconds = float(np.clip(E_FOLDS / lam, *HORIZON_BOUNDS)) if lam > 0 else HORIZON_BOUNDS[1]
    return max(5, round(seconds / dt))


def window_activity(prep: Prepared, starts: np.ndarray, horizon: int) -> np.ndarray:
    """Per window: the arm's travel (rad), the pendulum's travel (rad) and the command's std (columns)."""
    idx = starts[:, None] + np.arange(horizon + 1)[None, :]
    return np.column_stack([np.ptp(prep.phi[idx], axis=1), np.ptp(prep.theta_f[idx], axis=1), np.std(prep.u[idx], axis=1)])


def informative_starts(prep: Prepared, horizon: int, max_windows: int) -> tuple[list[int], int]:
    """(starts of the windows to predict, number of candidate windows). Candidates tile the valid span without
    overlap; a window is informative when the arm moves (≥ 3 encoder counts), the pendulum moves or the command
    varies by at least INFORMATIVE_SHARE of that activity's INFORMATIVE_PERCENTILE over all windows (a still tail
    after a swing-up is not); at most ``max_windows`` of them, evenly spread over the informative ones."""
    v = np.flatnonzero(prep.valid)
    cand = np.arange(v[0], v[-1] - horizon - 1, horizon)
    if len(cand) == 0:
        return [], 0
    act = window_activity(prep, cand, horizon)
    ref = np.percentile(act, INFORMATIVE_PERCENTILE, axis=0)
    floor = np.array([3 * prep.phi_lsb, 0.0, 0.0])
    ok = np.any((act >= INFORMATIVE_SHARE * ref) & (act > floor) & (ref > 0), axis=1)
    chosen = cand[ok] if ok.any() else cand
    if len(chosen) > max_windows:
        chosen = chosen[np.round(np.linspace(0, len(chosen) - 1, max_windows)).astype(int)]
    return [int(k) for k in chosen], len(cand)


def simulate_window(model: RigModel, prep: Prepared, fine: States, k: int, horizon: int,
                    substep_hz: float = 2000.0) -> tuple[np.ndarray, np.ndarray]:
    """(θ_f, φ) predicted for ticks k+1 … k+horizon, open loop with the recorded commands."""
    th, ph, _ = _track(model, prep, fine, k, horizon, substep_hz, stop=False)
    return th, ph


def _track(model: RigModel, prep: Prepared, fine: States, k: int, horizon: int, substep_hz: float,
           stop: bool) -> tuple[np.ndarray, np.ndarray, bool]:
    """(θ_f, φ, diverged) for ticks k+1 … k+horizon; with ``stop``, the simulation ends at divergence and the rest
    of the window is set at the divergence bounds."""
    th = np.full(horizon, np.nan)
    ph = np.full(horizon, np.nan)
    try:
        sim = start_simulator(model, prep, fine, k, 1.0 / prep.dt, substep_hz)
        D, _ = model.command_timing(round(prep.command_lag / prep.dt))  # the driver's ticks; the line the rest
        for j in range(horizon):
            sim.set_command(float(prep.u[max(k + j - D, 0)]))
            sim.advance(1)
            th[j] = sim.filtered_theta()[0]
            ph[j] = sim.phi
            if stop and not (abs(th[j] - prep.theta_f[k + 1 + j]) <= THETA_DIVERGED
                             and abs(ph[j] - prep.phi[k + 1 + j]) <= PHI_DIVERGED):
                break
    except (ArithmeticError, ValueError):  # a state that blew up
        pass
    seg = slice(k + 1, k + 1 + horizon)
    diverged = bool(np.any(~(np.abs(th - prep.theta_f[seg]) <= THETA_DIVERGED))
                    or np.any(~(np.abs(ph - prep.phi[seg]) <= PHI_DIVERGED)))
    if diverged and stop:
        j = int(np.argmax(~(np.abs(th - prep.theta_f[seg]) <= THETA_DIVERGED) | ~(np.abs(ph - prep.phi[seg]) <= PHI_DIVERGED)))
        th[j:] = prep.theta_f[seg][j:] + THETA_DIVERGED
        ph[j:] = prep.phi[seg][j:] + PHI_DIVERGED
    return th, ph, diverged


@dataclass(frozen=True)
class Prediction:
    """One model's predictions of the windows: per window the rms error of θ_f and φ (rad; a diverged window's
    error counted at the divergence bounds from where it diverged) and whether it diverged."""

    err_theta: np.ndarray
    err_phi: np.ndarray
    diverged: np.ndarray
    scale_theta: float  # spread of θ_f over the windows (rad)
    scale_phi: float  # spread of φ over the windows (rad; NaN: the arm does not move, φ is no test)

    @property
    def windows(self) -> int:
        return len(self.err_theta)

    @property
    def per_window(self) -> np.ndarray:
        """NRMSE of each window, mean over θ and φ (θ alone when the arm does not move)."""
        if not np.isfinite(self.scale_phi):
            return self.err_theta / self.scale_theta
        return 0.5 * (self.err_theta / self.scale_theta + self.err_phi / self.scale_phi)

    @property
    def nrmse_theta(self) -> float:
        return _rms([self.err_theta]) / self.scale_theta

    @property
    def nrmse_phi(self) -> float:
        return _rms([self.err_phi]) / self.scale_phi

    @property
    def nrmse(self) -> float:
        """Mean over θ and φ (θ alone when the arm does not move)."""
        return float(np.nanmean([self.nrmse_theta, self.nrmse_phi])) if self.windows else float("nan")


def scales(prep: Prepared, starts: list[int], horizon: int) -> tuple[float, float]:
    """(spread of θ_f, spread of φ) over the windows' samples (φ's NaN when the arm does not move in them)."""
    if not starts:
        return 1.0, float("nan")
    idx = (np.asarray(starts)[:, None] + 1 + np.arange(horizon)[None, :]).ravel()
    s_th = float(np.std(prep.theta_f[idx])) or 1.0
    s_ph = float(np.std(prep.phi[idx]))
    return s_th, (s_ph if prep.moves(prep.phi) and s_ph > 0 else float("nan"))


def predict(rig: RigConfig, effects: Effects | list[Effects], prep: Prepared, fine: States, starts: list[int],
            horizon: int, substep_hz: float = 2000.0, folds: list[int] | None = None) -> Prediction:
    """Open-loop multi-step prediction of θ_f and φ over ``horizon`` ticks from each start; ``effects`` one set, or
    one per fold with ``folds`` giving each window's fold."""
    sets = effects if isinstance(effects, list) else [effects]
    models = [RigModel.from_config(quiet(rig), e) for e in sets]
    which = folds if folds is not None else [0] * len(starts)
    e_th, e_ph, div = [], [], []
    for k, f in zip(starts, which, strict=True):
        th, ph, d = _track(models[f], prep, fine, k, horizon, substep_hz, stop=True)
        e_th.append(_rms([th - prep.theta_f[k + 1 : k + 1 + horizon]]))
        e_ph.append(_rms([ph - prep.phi[k + 1 : k + 1 + horizon]]))
        div.append(d)
    s_th, s_ph = scales(prep, starts, horizon)
    return Prediction(np.asarray(e_th), np.asarray(e_ph), np.asarray(div, bool), s_th, s_ph)


def compare(nominal: Prediction, augmented: Prediction, t_min: float = T_DIFFERENT) -> dict:
    """The augmented model's prediction against the nominal one's over the same windows: "diverges" when it diverges
    in more windows; else "improved"/"worse" when its mean NRMSE is lower/higher and the difference is significant —
    the paired t of the per-window NRMSE reaches ``t_min``, or that of their logarithms does (a window's error ratio:
    the per-window errors of an unstable plant are heavy-tailed, and two windows where the nominal model runs away
    must not hide a lower error in all the others), or the nominal model diverges in windows where it does not; else
    "unchanged"."""
    dn, da = int(nominal.diverged.sum()), int(augmented.diverged.sum())
    t = paired_t(nominal.per_window, augmented.per_window) if nominal.windows > 1 else 0.0
    t_log = 0.0
    if nominal.windows > 1 and np.all(nominal.per_window > 0) and np.all(augmented.per_window > 0):
        t_log = paired_t(np.log(nominal.per_window), np.log(augmented.per_window))
    better, poorer = augmented.nrmse < nominal.nrmse, augmented.nrmse > nominal.nrmse
    verdict = ("diverges" if da > dn else
               "improved" if better and (t >= t_min or t_log >= t_min or dn > da) else
               "worse" if poorer and (t <= -t_min or t_log <= -t_min) else "unchanged")
    return {"verdict": verdict, "paired_t": t, "paired_t_log": t_log, "nominal_diverged": dn, "augmented_diverged": da}


def _rms(parts: list[np.ndarray]) -> float:
    return float(np.sqrt(np.mean(np.concatenate(parts) ** 2))) if parts else float("nan")


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
