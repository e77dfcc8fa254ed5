"""Offline re-run of the observer and controller over a log's recorded samples.

The replay rule of furuta_rt.io.log_schema: for each tick in order, Measurement(t, θ, θ̇, φ) from the
logged SI values; ``reset`` true → Controller.reset(φ) first; Controller.update when the supervisor
state was one of log_schema.DRIVEN_STATES (a --swing-up log: its start-up calibration applied first), else
Controller.hold (u = 0). With the logged rig, mode and gains the replayed u
must equal the logged u bit for bit (the determinism check); with others it is what that controller
would have commanded on the same data (the plant did not see it: no feedback through the plant).
"""

from __future__ import annotations

import gc
import itertools
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from furuta_rt.config import CompMode, RigConfig
from furuta_rt.controller.controller import Controller, ControlOutput, Measurement
from furuta_rt.errors import UserError
from furuta_rt.experiment.plan import Excitation, plan_of_log
from furuta_rt.io.log_schema import DRIVEN_STATES
from furuta_rt.io.mcap_read import LogData, require_ticks
from furuta_rt.runtime.calibration import CALIBRATION_METADATA, StartupCalibration


@dataclass
class ReplayResult:
    t: np.ndarray
    u: np.ndarray  # replayed command (0 outside "balancing")
    u_lin: np.ndarray
    u_comp: np.ndarray
    phi_dot_hat: np.ndarray
    saturated: np.ndarray
    balancing: np.ndarray  # bool per tick
    u_logged: np.ndarray
    mode: str
    gains: tuple[float, float, float, float]
    same_config: bool  # replayed with the log's own rig, mode and gains
    converted: bool  # the log came from a recording: its u is not furuta-rt's output
    n_mismatch: int  # balancing ticks where u != logged u
    n_phi_dot_mismatch: int  # ticks where the replayed φ̂̇ != the logged one
    max_abs_du: float
    wall_seconds: float

    @property
    def exact(self) -> bool:
        return self.n_mismatch == 0

    @property
    def speed(self) -> float:
        """Replay speed in multiples of real time (loop only, reading excluded)."""
        span = float(self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0
        return span / self.wall_seconds if self.wall_seconds > 0 else float("inf")

    def verdict(self) -> str:
        """One line on how the replayed u compares with the logged one."""
        n = int(self.balancing.sum())
        diff = f"differs on {self.n_mismatch} of {n} balancing ticks (max |Δu| = {self.max_abs_du:.3g})"
        if self.converted:
            return f"recording converted from another source: its u is the recorded input, not furuta-rt's; replayed u {diff}"
        if self.same_config:
            if self.exact:
                also = " (and φ̂̇ on every tick)" if self.n_phi_dot_mismatch == 0 else ""
                return f"determinism check passed: replayed u equals the logged u exactly on all {n} balancing ticks{also}"
            return f"determinism check FAILED: replayed u {diff}"
        return f"replayed with mode {self.mode}, gains {list(self.gains)}: u {diff} from the logged run"


def apply_startup_calibration(log: LogData, active: np.ndarray, theta: list[float], phi: list[float]) -> None:
    """A --swing-up log's start-up calibration (its "calibration" metadata) applied in place to θ and φ from the
    first tick the controller drove on, as the daemon applied it (furuta_rt.runtime.calibration)."""
    meta = log.metadata.get(CALIBRATION_METADATA)
    if not meta or not active.any():
        return
    cal = StartupCalibration.from_metadata(meta)
    for k in range(int(np.argmax(active)), len(theta)):
        theta[k], phi[k] = cal.apply(theta[k], phi[k])


_PROGRESS_TICKS = 4096  # progress is reported at least this often (ticks)


def _segments(drives: np.ndarray, reset: np.ndarray, most: int) -> Iterator[tuple[int, int, bool]]:
    """(first, end, the controller drives) of the runs of ticks replayed alike: a run ends where ``drives`` changes,
    before a reset (so a reset is always a run's first tick) and at every multiple of ``most`` ticks."""
    n = len(drives)
    cuts = np.union1d(np.flatnonzero(drives[1:] != drives[:-1]) + 1, np.flatnonzero(reset))
    cuts = np.union1d(cuts, np.arange(most, n, most))
    bounds = [0, *(int(c) for c in cuts if 0 < c < n), n]
    for a, b in itertools.pairwise(bounds):
        yield a, b, bool(drives[a])


def replay_log(
    log: LogData,
    *,
    rig: RigConfig | None = None,
    mode: CompMode | None = None,
    gains: list[float] | np.ndarray | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ReplayResult:
    """Re-run the controller over ``log``'s ticks. Defaults: the log's rig, mode and gains.
    ``progress(done, total)`` is called every few thousand ticks."""
    n = require_ticks(log).n_ticks
    the_rig = rig or log.rig
    if the_rig is None:
        raise UserError(f"{log.path}: the log carries no usable rig config; give one with --config")
    the_mode = mode or log.mode or the_rig.compensation.mode
    the_gains = gains if gains is not None else log.gains
    ctrl = Controller.from_rig(the_rig, mode=the_mode, gains=the_gains)  # type: ignore[arg-type]
    plan = plan_of_log(log.metadata)
    if plan is not None:  # a designed experiment: the same excitation, stepped by the same driven ticks
        ctrl.excitation = Excitation(plan, log.run.get("rate_hz") or the_rig.control.rate_hz)
    same = (
        (rig is None or rig == log.rig)
        and (mode is None or mode == log.mode)
        and (gains is None or log.gains is None or [float(g) for g in gains] == log.gains)
    )
    tk = log.ticks
    t_l, th_l, thd_l, ph_l = (tk[k].tolist() for k in ("t", "theta", "theta_dot", "phi"))
    balancing = np.isin(tk["state"], DRIVEN_STATES)  # the controller drove the actuator
    apply_startup_calibration(log, balancing, th_l, ph_l)
    reset_l = tk["reset"].tolist()
    # the ControlOutputs of the ticks the controller drove, in order, and φ̂̇ of the others (held)
    outs: list[ControlOutput] = []
    held: list[float] = []
    update, hold, reset = ctrl.update, ctrl.hold, ctrl.reset
    # One Measurement refilled per tick: update and hold read its four fields and keep no reference to it (a new
    # object per tick was a seventh of the replay's time).
    m = Measurement(0.0, 0.0, 0.0, 0.0)

    def measured(a: int, b: int) -> Iterator[Measurement]:
        for m.t, m.theta, m.theta_dot, m.phi in zip(t_l[a:b], th_l[a:b], thd_l[a:b], ph_l[a:b], strict=True):
            yield m

    # The cyclic collector off while the outputs pile up (as in the daemon's loop, runtime.rt.freeze_gc): the loop
    # makes only tuples and floats, no cycles, and the collections their count triggers were a sixteenth of its time.
    collecting = gc.isenabled()
    gc.disable()
    start = time.perf_counter()
    try:
        for a, b, drives in _segments(balancing, tk["reset"], _PROGRESS_TICKS):
            if reset_l[a]:
                reset(ph_l[a])
            if drives:
                outs += map(update, measured(a, b))
            else:
                held += map(hold, measured(a, b))
            if progress is not None:
                progress(b, n)
    finally:
        if collecting:
            gc.enable()
    wall = time.perf_counter() - start
    u_arr, u_lin_arr, u_comp_arr, phd_arr = (np.zeros(n) for _ in range(4))
    sat_arr = np.zeros(n, dtype=bool)
    if outs:  # the named tuples as columns in one conversion (fields u, u_lin, u_comp, φ̂̇, saturated, swinging)
        table = np.fromiter(itertools.chain.from_iterable(outs), float, len(outs) * len(ControlOutput._fields))
        table = table.reshape(len(outs), len(ControlOutput._fields))
        for arr, column in ((u_arr, 0), (u_lin_arr, 1), (u_comp_arr, 2), (phd_arr, 3), (sat_arr, 4)):
            arr[balancing] = table[:, column]
    phd_arr[~balancing] = held
    logged = tk["u"]
    diff = (u_arr != logged) & balancing
    return ReplayResult(
        t=tk["t"], u=u_arr, u_lin=u_lin_arr, u_comp=u_comp_arr, phi_dot_hat=phd_arr,
        saturated=sat_arr, balancing=balancing, u_logged=logged, mode=str(the_mode),
        gains=ctrl.gains, same_config=same, converted=log.converted, n_mismatch=int(diff.sum()),
        n_phi_dot_mismatch=int(np.sum(phd_arr != tk["phi_dot_hat"])),
        max_abs_du=float(np.max(np.abs(u_arr - logged)[balancing], initial=0.0)), wall_seconds=wall,
    )
