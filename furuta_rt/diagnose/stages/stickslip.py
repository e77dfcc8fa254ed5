"""Stick–slip windows: where the arm sticks, eq. 4 only bounds the friction; the evidence is *when it breaks away*.

A run of at least STICK_SECONDS at one encoder count is the arm at rest (moving, it would cover less than
one count in that time). The regression of eq. 4 leaves those stretches out: while the arm is stuck its
friction torque is whatever holds it (eq. 2, set-valued, |held torque| ≤ Fs), so the residual carries no
information there. The data's *timing* does: the arm stays put until the torque it must hold first exceeds
the breakaway torque Fs, then slides against Fc. The held torque is practically the command (the
pendulum's share γ cos θ θ̈ is ~1e-4 N m near upright), and the command varies from tick to tick, so the
instant of breakaway is sharp: these windows measure the breakaway torque, and they time the actuator
(a transport delay moves every breakaway).

Each window starts inside a stick (φ̇ = 0, φ at the measured count), WINDOW_LEAD before it ends, and runs
WINDOW_TAIL past it. The pendulum is teacher-forced: θ and θ̇ are reset to the reconstructed ones every
tick (upright, the pendulum is unstable, and left alone it would leave the data within tenths of a
second; its effect on the arm is small, but it must be the data's). The arm is simulated by
furuta_rt.sim.simulator.Simulator with the recorded commands — eq. 4, the set-valued friction law and the
actuator chain of the shared model. A window's error is the squared distance of the simulated arm angle from
the measured encoder cells (the count ± half a count), summed over its ticks, with the unknown position inside
the first cell profiled out: motion within a count is invisible to the encoder, and counts as no error.

Parameters are chosen on these windows the way the regression chooses nonlinear ones
(furuta_rt.diagnose.regression.fitting): on a grid, with blocked cross-validation over windows in time order (each
block's error at the value best on the other blocks), and accepted by the same rules (held-out gain,
BIC penalty on the number of windows, significance of the departure from the model without it).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.judgement.verify import quiet, start_simulator
from furuta_rt.diagnose.regression.fitting import paired_t, vertex
from furuta_rt.diagnose.regression.selection import Thresholds
from furuta_rt.diagnose.regression.states import Prepared, States
from furuta_rt.model.effects import Effects
from furuta_rt.model.rig import RigModel

STICK_SECONDS = 0.2  # a run this long at one encoder count is a stick
SETTLE_SECONDS = 0.02  # after a run starts: the arm has come to rest
WINDOW_LEAD = 0.3  # s before the count changes (or from the stick's start + SETTLE, if later)
WINDOW_TAIL = 0.15  # s after the count changes
MAX_WINDOWS = 20  # evenly spread over the recording (each costs a simulation per parameter value)
MIN_WINDOWS = 8
SUBSTEP_HZ = 2000.0  # the delay line's resolution is one substep

# grids: sliding level (when the regression did not select one: its provisional value, the windows only decide whether
# it is there — they measure the breakaway, the sliding rows the level); breakaway torque as a multiple of the
# sliding level; transport delay in s
COULOMB_RATIOS = (1.0,)
STICTION_RATIOS = (1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0)
DELAYS = (0.0, 0.001, 0.002, 0.003, 0.004, 0.006, 0.008, 0.011)
RETIME_SE, RETIME_STEP = 4.0, 0.0005  # a delay the rows found is re-timed within 4 of their se (se ≥ half this step)
REL_APART, T_APART = 0.01, 3.0  # look-alikes told apart: by ≥ 1 % and consistently, or by ≥ 10 % (as in the engine)
LUGRE_VS_RATIOS = (0.2, 0.5, 1.0, 2.0, 4.0)  # Stribeck speed, times the rig's [compensation.lugre] vs
LUGRE_EXPERIMENT = (
    "a slow constant-velocity arm sweep at several speeds around vs (LuGre's friction falls from Fs to Fc over "
    "the speed vs, set-valued stiction drops at once) or small torque steps below the breakaway (LuGre creeps, "
    "stiction holds)"
)


@dataclass(frozen=True)
class Window:
    start: int  # sample the simulation starts from
    horizon: int  # ticks simulated
    stick_end: int  # first sample at a new count (stick windows)
    phi_dot: float = 0.0  # the arm's velocity at the start (0: at rest, in a stick)


def stick_runs(prep: Prepared) -> list[tuple[int, int]]:
    """[start, stop) of the runs of ≥ STICK_SECONDS at one encoder count, inside the valid part with room for a tail."""
    cnt = np.round(prep.phi / prep.phi_lsb).astype(np.int64)
    start = np.flatnonzero(np.concatenate([[True], np.diff(cnt) != 0]))
    stop = np.concatenate([start[1:], [len(cnt)]])
    need = round(STICK_SECONDS / prep.dt)
    tail = round(WINDOW_TAIL / prep.dt)
    valid = np.flatnonzero(prep.valid)
    lo, hi = valid[0], valid[-1] - tail - 1
    return [(int(a), int(b)) for a, b in zip(start, stop, strict=True) if b - a >= need and a >= lo and b <= hi]


def windows(prep: Prepared) -> list[Window]:
    """One window per stick (at most MAX_WINDOWS, evenly spread over the recording)."""
    lead, settle, tail = (round(s / prep.dt) for s in (WINDOW_LEAD, SETTLE_SECONDS, WINDOW_TAIL))
    out = [Window(max(a + settle, b - lead), b - max(a + settle, b - lead) + tail, b) for a, b in stick_runs(prep)]
    if len(out) > MAX_WINDOWS:
        out = [out[i] for i in np.linspace(0, len(out) - 1, MAX_WINDOWS).round().astype(int)]
    return out


def simulate_arm(model: RigModel, prep: Prepared, fine: States, w: Window, substep_hz: float = SUBSTEP_HZ) -> np.ndarray:
    """φ over ticks w.start+1 … w.start+w.horizon: the arm simulated from ``w.phi_dot``, the pendulum teacher-forced."""
    k = w.start
    sim = start_simulator(model, prep, fine, k, 1.0 / prep.dt, substep_hz, phi_dot=w.phi_dot)
    D, _ = model.command_timing(round(prep.command_lag / prep.dt))  # the driver's ticks; the line the rest
    h = w.horizon
    ahead = slice(k + 1, k + 1 + h)  # the pendulum forced along the window's ticks, the commands D ticks behind
    forced = zip(prep.u[np.maximum(np.arange(k - D, k - D + h), 0)].tolist(),
                 (fine.theta[ahead] - model.theta_offset).tolist(), fine.theta_dot[ahead].tolist(), strict=True)
    out = np.empty(h)
    for j, (u, theta, theta_dot) in enumerate(forced):
        sim.set_command(u)
        sim.advance(1)
        out[j] = sim.phi
        sim.theta = theta
        sim.theta_dot = theta_dot
    return out


def window_errors(rig: RigConfig, effects: Effects, prep: Prepared, fine: States, wins: list[Window],
                  substep_hz: float = SUBSTEP_HZ) -> np.ndarray:
    """Per window: Σ (|φ_sim + δ − φ| − half a count)₊² over its ticks (rad²), minimised over the start's position δ
    within its count (``cell_error``)."""
    model: RigModel | None = None
    same = (id(prep), rig.model_dump_json(), effects.model_dump_json(), substep_hz)
    out = np.empty(len(wins))
    for i, w in enumerate(wins):
        done = fine.simulations.get((*same, w))  # a window the stages already simulated with this model
        if done is None:
            model = model or RigModel.from_config(quiet(rig), effects)
            done = fine.simulations[(*same, w)] = (prep, simulate_arm(model, prep, fine, w, substep_hz))
        e = done[1] - prep.phi[w.start + 1 : w.start + 1 + w.horizon]
        out[i] = cell_error(e, prep.phi_lsb)
    return out


def cell_error(e: np.ndarray, lsb: float, iterations: int = 50) -> float:
    """min over δ in [−lsb/2, lsb/2] of Σ (|e + δ| − lsb/2)₊², exactly (to lsb·2⁻⁵⁰): the sum is convex in δ, its
    derivative monotone, so the optimum is found by bisection on the derivative. A trajectory that stays within one
    count of the data is no error at all (a grid over δ left up to half its step of spurious error per tick, the size
    of the differences between models that all fit the sticks, and made the windows' gains noise)."""
    half = 0.5 * lsb

    def slope(d: float) -> float:
        x = e + d
        return float(np.sum(np.maximum(np.abs(x) - half, 0.0) * np.sign(x)))

    lo, hi = -half, half
    if slope(lo) >= 0.0:
        hi = lo
    elif slope(hi) <= 0.0:
        lo = hi
    else:
        for _ in range(iterations):
            mid = 0.5 * (lo + hi)
            if slope(mid) > 0.0:
                hi = mid
            else:
                lo = mid
    d = 0.5 * (lo + hi)
    return float(np.sum(np.maximum(np.abs(e + d) - half, 0.0) ** 2))


# ------------------------------------------------------------------------------------ profiling
@dataclass
class WindowFit:
    """One effect's parameter chosen on the windows (grid, blocked CV), against the model without it."""

    name: str
    param: str
    value: float  # optimum on all windows
    null: float  # the value that means "absent" (Fs = Fc, delay = 0)
    grid: np.ndarray
    errors: np.ndarray  # (grid, windows)
    fold_values: np.ndarray
    cv_blocks: np.ndarray  # held-out error per block
    base_blocks: np.ndarray  # error per block of the model without the effect
    step: float  # local grid step at the optimum
    support: float | None = None  # input_delay: held-out gain of the arm regression (sliding rows) at this delay
    paired: bool = False  # significance by the blocks' paired improvement (a limit has no "departure" to test)
    retimed: bool = False  # input_delay the sliding rows found, re-timed on the windows (within their uncertainty)

    @property
    def cv(self) -> float:
        return float(self.cv_blocks.sum())

    @property
    def base(self) -> float:
        return float(self.base_blocks.sum())

    @property
    def gain(self) -> float:
        return (self.base - self.cv) / self.base if self.base > 0 else 0.0

    @property
    def se(self) -> float:
        B = len(self.fold_values)
        spread = float(np.sqrt((B - 1) / B * np.sum((self.fold_values - self.fold_values.mean()) ** 2))) if B > 1 else np.inf
        return max(spread, 0.5 * self.step)

    @property
    def t(self) -> float:
        if self.paired:
            return paired_t(self.base_blocks, self.cv_blocks)
        return abs(self.value - self.null) / self.se

    def accepted(self, th: Thresholds) -> bool:
        """The regression's rules: held-out gain ≥ min_gain and above a BIC penalty on the number of windows; the
        departure from the null value significant (t ≥ t_min, or t ≥ t_strong with a strong gain)."""
        n = self.errors.shape[1]
        penalty = np.log(max(n, 2)) * self.cv / n
        significant = self.t >= th.t_min or (self.gain >= th.strong_gain and self.t >= th.t_strong)
        supported = self.name != "input_delay" or self.retimed or (self.support is not None and self.support >= th.min_gain)
        return self.base > 0 and self.gain >= th.min_gain and self.base - self.cv > penalty and significant and supported

    def value_on(self, mask: np.ndarray) -> float:
        """The optimum on the windows in ``mask`` only (e.g. those before a held-out part)."""
        total = self.errors[:, mask].sum(1)
        return vertex(self.grid, total, int(np.argmin(total)))

    def as_json(self) -> dict:
        return {"name": self.name, self.param: self.value, "se": self.se, "t": self.t, "cv_gain": self.gain,
                "regression_support": self.support,
                "fold_values": self.fold_values.tolist(), "grid": self.grid.tolist(),
                "error_curve": self.errors.sum(1).tolist()}


def blocks_of(n: int, count: int) -> list[np.ndarray]:
    return [b for b in np.array_split(np.arange(n), min(count, n)) if len(b)]


def profile(name: str, param: str, errors_of: Callable[[float], np.ndarray], grid: list[float], null: float,
            base: np.ndarray, n_blocks: int) -> WindowFit:
    """Errors on the grid (refined by the two midpoints beside the coarse optimum), the optimum by a parabola
    through the error curve, and each block's held-out error at the value best on the other blocks."""
    values = list(grid)
    rows = [base if v == null else errors_of(v) for v in values]
    i = int(np.argmin([r.sum() for r in rows]))
    for j in (i - 1, i + 1):
        if 0 <= j < len(values):
            mid = 0.5 * (values[i] + values[j])
            values.append(mid)
            rows.append(errors_of(mid))
    order = np.argsort(values)
    x = np.asarray(values)[order]
    E = np.asarray(rows)[order]
    blocks = blocks_of(E.shape[1], n_blocks)
    total = E.sum(1)
    best_i = int(np.argmin(total))
    value = vertex(x, total, best_i)
    folds, cv = np.empty(len(blocks)), np.empty(len(blocks))
    for b, idx in enumerate(blocks):
        train = total - E[:, idx].sum(1)
        g = int(np.argmin(train))
        folds[b] = vertex(x, train, g)
        cv[b] = E[g, idx].sum()
    step = float(np.min(np.abs(np.diff(x)[max(best_i - 1, 0) : best_i + 1]))) if len(x) > 1 else 0.0
    return WindowFit(name, param, value, null, x, E, folds, cv, np.array([base[idx].sum() for idx in blocks]), step)


# ------------------------------------------------------------------------------------ the stage
@dataclass
class WindowStage:
    """What a window stage says: the effects it adds, look-alikes, and the numbers behind them."""

    windows: list[Window]
    added: dict[str, dict[str, float]] = field(default_factory=dict)
    fits: dict[str, WindowFit] = field(default_factory=dict)  # accepted
    tried: list[dict] = field(default_factory=list)
    ambiguities: list[dict] = field(default_factory=list)
    lookalikes: list[dict] = field(default_factory=list)
    replaces: list[str] = field(default_factory=list)  # found effects the stage's model takes the place of

    def as_json(self) -> dict:
        return {"windows": len(self.windows), "added": self.added, "tried": self.tried}


EXPERIMENT = (
    "a slow ramp of the command with the arm at rest (the breakaway torque is where it starts to move, "
    "independent of timing) or a square-wave command (a transport delay shifts every start by the same time)"
)


GRIDS: dict[str, tuple[str, tuple[float, ...]]] = {
    "arm_coulomb": ("Fc", COULOMB_RATIOS), "arm_stiction": ("Fs", STICTION_RATIOS), "input_delay": ("delay", DELAYS),
}
TIMING = ("arm_stiction", "input_delay")  # the look-alike pair of the breakaways' timing


def _profile(name: str, current: dict[str, dict[str, float]], base: np.ndarray,
             errors: Callable[[dict[str, dict[str, float]]], np.ndarray], n_blocks: int,
             support: Callable[[float], float | None], coulomb: float | None = None,
             retime: float | None = None) -> WindowFit:
    """``name`` added to the model ``current``, its parameter profiled on the windows (Fs from the sliding level up,
    Fc around the provisional level ``coulomb``). ``retime``: input_delay is already in ``current`` (the sliding
    rows found it): its value is profiled on the windows against the rows' value, within ``retime`` of it."""
    param, grid = GRIDS[name]
    null = current["arm_coulomb"]["Fc"] if name == "arm_stiction" else 0.0
    scale = {"arm_stiction": null, "arm_coulomb": coulomb or 0.0}.get(name)
    values = [scale * r for r in grid] if scale is not None else list(grid)
    if retime is not None:
        null = current[name][param]
        values = sorted({null, *(v for v in values if abs(v - null) <= retime)})
    fit = profile(name, param, lambda v: errors({**current, name: {param: v}}), values, null, base, n_blocks)
    if name == "arm_coulomb" or retime is not None:
        fit.paired = True  # one value / a value already there: significance by the blocks' paired improvement
    if name == "input_delay":
        fit.support = support(fit.value) if retime is None else None
        fit.retimed = retime is not None
    return fit


def assess(rig: RigConfig, found: dict[str, dict[str, float]], prep: Prepared, fine: States, th: Thresholds,
           delay_support: Callable[[float], float | None], wins: list[Window] | None = None,
           only: set[str] | None = None, lugre: bool = True, coulomb: float | None = None,
           delay_se: float | None = None) -> WindowStage | None:
    """Forward selection of arm_stiction (on top of Coulomb friction) and input_delay (when none was found) on the
    stick windows, starting from the effects ``found``, then LuGre in place of Coulomb + stiction (``lugre``).
    ``only``: the candidates to try (a second reading, on a better sliding level). None when there are too few
    sticks.

    ``delay_support(d)``: the arm regression's held-out gain with a delay d (None when the arm equation has too
    few sliding rows). A delay must also pay on the sliding rows: the breakaways alone cannot always tell a late
    breakaway (delay) from a high one (stiction), the sliding arm can.

    ``coulomb``: without Coulomb friction in ``found``, its provisional sliding level (the arm regression's fit
    of it on the sliding rows): Coulomb friction at that level is then a candidate of the windows too (an arm that
    sticks needs a dry friction; a deadzone or an input gain, which the sliding rows may favour alike, lets it
    creep or coast instead), and a breakaway torque above it is tried once it is in.

    ``delay_se``: the standard error of an input_delay the sliding rows found (in ``found``). The breakaways time
    it more directly than the rows (which may hold brief sticks, where the friction is the held torque, not ±Fc),
    and a delay set wrong there reads as a breakaway torque (a late breakaway): the delay is re-timed on the windows,
    within RETIME_SE of its standard errors of the rows' value, as a candidate beside the breakaway torque."""
    wins = windows(prep) if wins is None else wins
    if len(wins) < MIN_WINDOWS or ("arm_coulomb" not in found and not (coulomb or 0.0) > 0):
        return None
    out = WindowStage(wins)
    current = dict(found)

    def errors(eff: dict[str, dict[str, float]]) -> np.ndarray:
        return window_errors(rig, Effects.model_validate(eff), prep, fine, wins)

    base = errors(current)
    first: dict[str, WindowFit] = {}
    retime = (RETIME_SE * max(delay_se, 0.5 * RETIME_STEP) if delay_se is not None and "input_delay" in found
              and prep.commanded else None)

    def eligible(n: str) -> bool:
        return ((n not in current or (n == "input_delay" and retime is not None and n not in out.added))
                and (prep.commanded or n != "input_delay") and (only is None or n in only)
                and not (n == "input_delay" and "command_latency" in current)
                and (n != "arm_stiction" or "arm_coulomb" in current))

    def fit_of(name: str) -> WindowFit:
        return _profile(name, current, base, errors, th.n_blocks, delay_support, coulomb,
                        retime if name in found and name == "input_delay" else None)

    names = [n for n in GRIDS if eligible(n)]
    while names:
        fits = {name: fit_of(name) for name in names}
        first = first or dict(fits)
        ok = [f for f in fits.values() if f.accepted(th)]
        best = max(ok, key=lambda f: f.gain) if ok else None
        out.tried += [{"step": len(out.added), **f.as_json(), "accepted": f is best} for f in fits.values()]
        if best is None:
            break
        current[best.name] = {best.param: best.value}
        out.added[best.name] = {best.param: best.value}
        out.fits[best.name] = best
        if best.retimed:
            out.replaces.append(best.name)
        base = errors(current)
        # what paid on its own is tried on top, if its value there still lowers the error
        names = [f.name for f in ok if f is not best
                 and base.sum() - errors({**current, f.name: {f.param: f.value}}).sum() >= th.min_gain * base.sum()]
        if best.name == "arm_coulomb":  # the timing candidates afresh on top of the sliding level (a breakaway above it)
            names, first = [n for n in GRIDS if eligible(n)], {}
    _lookalikes(out, first, th)
    if lugre and "arm_stiction" in out.added and "arm_lugre" not in found:
        _lugre(rig, current, out, first["arm_stiction"].base_blocks, errors, th)
    return out


def _lugre(rig: RigConfig, current: dict[str, dict[str, float]], out: WindowStage, coulomb_blocks: np.ndarray,
           errors: Callable[[dict[str, dict[str, float]]], np.ndarray], th: Thresholds) -> None:
    """LuGre (eq. 3) in place of Coulomb + stiction: the breakaway as the Stribeck peak Fs of a bristle model,
    falling to Fc over the speed vs. Fc and Fv stay the regression's (the sliding rows are well above vs), Fs and
    then vs are profiled on the stick windows; σ0 and σ1 come from the rig's [compensation.lugre] (the presliding
    displacement Fc/σ0 is far below one encoder count: the data cannot give them). The better of the two models of
    the breakaways is reported; when the blocks cannot tell them apart, the pair is declared ambiguous."""
    cfg = rig.compensation.lugre
    fc = current["arm_coulomb"]["Fc"]
    rest = {k: v for k, v in current.items() if k not in ("arm_coulomb", "arm_stiction", "arm_viscous")}
    law = {"sigma0": cfg.sigma0, "sigma1": cfg.sigma1, "Fc": fc, "Fv": current.get("arm_viscous", {}).get("Fv", 0.0)}

    def model(fs: float, vs: float) -> dict[str, dict[str, float]]:
        return {**rest, "arm_lugre": {**law, "Fs": max(fs, fc), "vs": vs}}

    vs0 = cfg.vs
    coulomb = coulomb_blocks
    f_fs = profile("arm_lugre", "Fs", lambda v: errors(model(v, vs0)), [fc * r for r in STICTION_RATIOS[1:]], -1.0,
                   np.zeros(len(out.windows)), th.n_blocks)
    fs = f_fs.value
    f_vs = profile("arm_lugre", "vs", lambda v: errors(model(fs, v)), [vs0 * r for r in LUGRE_VS_RATIOS], -1.0,
                   np.zeros(len(out.windows)), th.n_blocks)
    lugre = model(fs, f_vs.value)["arm_lugre"]
    stiction = out.fits["arm_stiction"]
    lugre_cv, stiction_cv = f_vs.cv_blocks, stiction.cv_blocks
    rel = (lugre_cv.sum() - stiction_cv.sum()) / coulomb.sum()  # difference of the held-out gains over Coulomb alone
    t = paired_t(stiction_cv, lugre_cv)  # > 0: LuGre better
    entry = {"effects": ["arm_stiction", "arm_lugre"], "experiment": LUGRE_EXPERIMENT}
    out.tried.append({"step": len(out.added), "name": "arm_lugre", **lugre, "cv_gain": 1.0 - lugre_cv.sum() / coulomb.sum(),
                      "against_stiction": rel, "paired_t": t})
    lugre_apart = rel <= -REL_APART and (t >= T_APART or rel <= -10 * REL_APART)  # LuGre clearly better
    stiction_apart = rel >= REL_APART and (-t >= T_APART or rel >= 10 * REL_APART)
    if lugre_apart:
        out.added = {k: v for k, v in out.added.items() if k != "arm_stiction"} | {"arm_lugre": lugre}
        out.fits["arm_lugre"] = replace(f_vs, base_blocks=coulomb_blocks)
        out.fits.pop("arm_stiction")
        out.replaces = ["arm_coulomb", "arm_viscous"]
        out.lookalikes.append({**entry, "reported": "arm_lugre", "reason": (
            f"LuGre (Fs = {fs:.3g}, vs = {f_vs.value:.3g}) fits the breakaways better than stiction "
            f"({100 * rel:+.1f} % held-out error, paired t = {t:.1f})")})
    elif stiction_apart:
        out.lookalikes.append({**entry, "reported": "arm_stiction", "reason": (
            f"LuGre in its place fits the breakaways worse ({100 * rel:+.1f} % held-out error, paired t = {-t:.1f})")})
    else:
        out.ambiguities.append({
            **entry, "reported": "arm_stiction", "alternative": {"name": "arm_lugre", "params": lugre},
            "alternative_model": {"arm_lugre": lugre}, "cv_difference": rel, "paired_t": -t,
            "replaced": [n for n in ("arm_coulomb", "arm_viscous") if n in current],
            "reason": f"on the stick windows LuGre (Fs = {fs:.3g}, vs = {f_vs.value:.3g}) fits almost as well "
                      f"({100 * rel:+.2f} % held-out error, paired t = {-t:.1f})"})


def values_before(out: WindowStage, stop: int, min_windows: int = MIN_WINDOWS) -> dict[str, dict[str, float]] | None:
    """The stage's effects' parameters chosen on the windows that end before sample ``stop`` only (None when there
    are fewer than ``min_windows`` of them)."""
    mask = np.array([w.start + w.horizon < stop for w in out.windows])
    if mask.sum() < min_windows:
        return None
    return {name: {**out.added[name], f.param: f.value_on(mask)} for name, f in out.fits.items()}


def _lookalikes(out: WindowStage, first: dict[str, WindowFit], th: Thresholds, rel_apart: float = 0.01,
                t_apart: float = 3.0) -> None:
    """A breakaway torque and a transport delay both move the breakaways: when one was selected, the other in
    its place (from the same starting model) is compared on the held-out blocks."""
    first = {k: v for k, v in first.items() if k in TIMING}
    added = [n for n in out.added if n in TIMING]
    if len(first) < 2 or len(added) != 1:
        return
    name = added[0]
    other = next(n for n in first if n != name)
    a, b = first[name], first[other]
    rel = (b.cv - a.cv) / a.base  # difference of the held-out gains over the model with neither
    t = paired_t(b.cv_blocks, a.cv_blocks)
    pair = [name, other]
    if b.accepted(th) and not (rel >= rel_apart and (t >= t_apart or rel >= 10 * rel_apart)):
        out.ambiguities.append({
            "effects": pair, "reported": name, "alternative": {"name": other, "params": {b.param: b.value}},
            "alternative_model": {other: {b.param: b.value}}, "cv_difference": rel, "paired_t": t,
            "reason": f"on the stick windows {other} fits almost as well ({100 * rel:+.2f} % held-out error, paired t = {t:.1f})",
            "experiment": EXPERIMENT,
        })
    else:
        if b.accepted(th):
            why = f"{other} in its place fits the breakaways worse ({100 * rel:+.1f} % held-out error, paired t = {t:.1f})"
        elif b.support is not None and b.support < th.min_gain <= b.gain:
            why = (f"{other} in its place ({b.param} = {b.value:.3g}) moves the breakaways too, but the sliding arm contradicts "
                   f"it (arm regression held-out error {-100 * b.support:+.0f} %)")
        else:
            why = f"{other} in its place is not supported (held-out gain {100 * b.gain:.1f} %, t = {b.t:.1f})"
        out.lookalikes.append({"effects": pair, "reported": name, "reason": why, "experiment": EXPERIMENT})


def describe(out: WindowStage, found: dict[str, dict[str, float]]) -> str:
    """One sentence: what the stick windows say."""
    n = len(out.windows)
    if not out.added:
        return f"arm sticks: {n} sticks, their breakaways as the model predicts (no breakaway torque above Fc, no extra delay)"
    parts = []
    fc = found.get("arm_coulomb", {}).get("Fc")
    if "arm_stiction" in out.fits:
        f = out.fits["arm_stiction"]
        above = f", above the sliding level Fc = {fc:.3g}" if fc else ""
        parts.append(f"the arm stays stuck until it holds Fs = {f.value:.3g} N m{above} "
                     f"(held-out error of the breakaways −{100 * f.gain:.0f} %)")
    if "input_delay" in out.fits:
        f = out.fits["input_delay"]
        parts.append(f"every breakaway comes {1e3 * f.value:.1f} ms late: a transport delay "
                     f"(held-out error −{100 * f.gain:.0f} %)")
    return f"arm sticks ({n} windows): " + "; ".join(parts)
