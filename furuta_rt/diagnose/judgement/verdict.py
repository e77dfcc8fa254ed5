"""An honest verdict per equation of eq. 4, and where what stays unexplained sits.

For each equation (arm, pendulum) the rms of the nominal residual, of the final (augmented) residual and of the
sensor noise floor (furuta_rt.diagnose.judgement.noise) are compared, all relative to the equation's torque scale
(furuta_rt.diagnose.judgement.locate.torque_scale). The test, on B contiguous time blocks of the equation's rows (which
accounts for the residual's correlation in time: the blocks, not the samples, are the independent units):

    d_b = ms(residual in block b) − K² · ms(noise floor draws in block b),   t = mean(d) / (sd(d)/√B)

and the residual is *within the noise floor* unless t > T_CRIT (one-sided t test at 0.5 % with B − 1 degrees of
freedom) or at least 14 of the 16 blocks exceed it (a sign test, binomial p = 0.2 %: a large excess that varies
much between blocks has a small t), or unless the per-band test (``band_t``) finds it above the floor in one octave
band below the kernel's cut-off (a low-frequency mismatch meets there only its own band's floor, which the
time-domain test dilutes with the floor's high-frequency power). K = FLOOR_ACCURACY is the accuracy of the floor
estimate itself: on the simulator, where the true states are known, the Monte Carlo floor is 0.81–1.22× (rms) the
true sensor part of the residual on every null case.

Verdicts: ``consistent`` (the nominal residual is within the floor and no effect was selected), ``explained`` (it
is not, or effects were selected — their own significance test, furuta_rt.diagnose.regression.selection, is more specific than the
size test — and the augmented residual is within the floor), ``partly_explained`` (effects remove at least half of
the excess over the floor and a significant part remains), ``unexplained`` (otherwise), ``not_assessed`` (too few
usable rows). A residual whose size is within the floor but which follows a possible cause's signature beyond
chance (below) is not consistent (nor explained): that test is specific, so it sees mismatches smaller than the
omnibus size test can.

For a remainder, where it sits (times, regions, the signals it follows, its frequency band) and what outside the
library could produce it: the remaining residuals of both equations are regressed, jointly, on the sensitivity of
FurutaPlant.inverse_dynamics to each plant parameter of the rig config, to a θ sensor scale and to the sign of
each angle, and (arm) to a compliant motor–arm coupling's own column, −τ̈_command (``compliance_column``: beyond the
rotor's inertia, which is a library effect) — possible causes for the person to check in the rig; never effects —,
first among them "an unmodelled compliance or mode" when the gate's band test found effects of the equation whose
fitted values depend on the frequency band (``mode_cause``; furuta_rt.diagnose.stages.gate.band_check); the remainder's
spectrum against the data's (``signature``) says in which band it sits (a narrow peak the data does not have points to an
unmodelled compliance or mode).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from furuta_rt.diagnose.judgement import noise
from furuta_rt.diagnose.judgement.locate import Location, describe, locate, torque_scale
from furuta_rt.diagnose.regression.library import ARM, PEND, Context
from furuta_rt.diagnose.regression.states import States
from furuta_rt.model.parameters import LumpedParameters
from furuta_rt.model.plant import FurutaPlant

N_BLOCKS = 16
T_CRIT = 2.95  # one-sided 0.5 % point of Student's t with 15 degrees of freedom
SIGN_MIN = 14  # of 16 blocks above the floor: one-sided binomial p = 0.2 % under H0 (the sign test)
SIZE_MAX = 2.0  # a residual whose rms exceeds SIZE_MAX·K times the floor's is never within it (the size guard)
FLOOR_ACCURACY = 1.3  # the floor estimate is within this factor (rms) of the true sensor part (see the docstring)
MIN_ROWS = 200
BAND_SEGMENT_S = 8.0  # s, Welch segment of the per-band test (band_t)
BAND_MIN_SEGMENTS = 6  # fewer (a recording shorter than ~28 s): the per-band test is not made
BAND_P = 0.001  # one-sided level of the per-band test, shared (Bonferroni) over its octave bands
PARTLY = 0.5  # effects must remove at least this share of the excess over the floor for `partly_explained`
CAUSE_T = 4.0  # a possible cause must be this many standard errors from zero ...
CAUSE_REMOVES = 0.1  # ... and remove at least this share of the remaining (weighted) residual where it acts

# plant parameters of each parametrisation that are not library effects (the arm inertia is one), with a name
PLANT_CAUSES: dict[str, tuple[tuple[str, str], ...]] = {
    "thesis": (("Jp", "pendulum inertia"), ("l", "pendulum length"), ("M", "tip mass"), ("m", "pendulum mass"),
               ("r", "arm length")),
    "general": (("J2", "pendulum inertia"), ("l2", "pendulum centre of mass"), ("m2", "pendulum mass"),
                ("L1", "arm length")),
    "lumped": (("alpha", "pendulum inertia α"), ("gamma", "coupling γ"), ("epsilon", "gravity torque ε")),
}
LOOKALIKE_MARGIN = 0.05  # a cause removing within this share of the first one's is reported as its look-alike
Remaining = tuple[np.ndarray, np.ndarray, float, np.ndarray]  # (residual, rows, floor ms, floor draws on the rows)
STEP = 1e-3  # relative step of the sensitivity columns


@dataclass
class EquationVerdict:
    equation: str
    verdict: str
    residual_nominal: float
    residual_augmented: float
    noise_floor: float
    t_nominal: float = float("nan")
    t_augmented: float = float("nan")
    reason: str = ""
    effects: tuple[str, ...] = ()
    unexplained: dict | None = None
    remainder: Location | None = field(default=None, repr=False)
    band_nominal: dict = field(default_factory=dict)  # the per-band test's band of largest excess (band_t)
    band_augmented: dict = field(default_factory=dict)
    detectable: dict[str, float] = field(default_factory=dict)  # consistent: cause → smallest relative change seen

    def as_json(self) -> dict:
        out = {"verdict": self.verdict, "residual_nominal": self.residual_nominal,
               "residual_augmented": self.residual_augmented, "noise_floor": self.noise_floor,
               "test": {"t_nominal": self.t_nominal, "t_augmented": self.t_augmented, "t_crit": T_CRIT,
                        "blocks": N_BLOCKS, "floor_accuracy": FLOOR_ACCURACY,
                        "band_nominal": self.band_nominal or None, "band_augmented": self.band_augmented or None},
               "unexplained": self.unexplained}
        if self.reason:
            out["reason"] = self.reason
        if self.detectable:
            out["detectable_change"] = self.detectable
        return out


def block_t(r: np.ndarray, floor: np.ndarray, n_blocks: int = N_BLOCKS) -> float:
    """t of mean(ms_b(r) − K²·ms_b(floor)) over contiguous blocks (r: residual on the rows; floor: (draws, rows)).

    A large excess that varies much between blocks has a small t, so the sign test backs it: when at least SIGN_MIN
    of the B blocks exceed the floor (one-sided binomial p < 0.5 % under H0), t is +inf. An excess concentrated in a
    few blocks (a step's transient) passes neither, so a size guard backs both: a residual whose rms is more than
    SIZE_MAX·K times the floor's cannot be the sensors' (the floor is within K of their true part), t is +inf."""
    if np.mean(r**2) > (SIZE_MAX * FLOOR_ACCURACY) ** 2 * np.mean(floor**2):
        return float("inf")
    edges = np.linspace(0, len(r), n_blocks + 1).round().astype(int)
    d = np.array([np.mean(r[a:b] ** 2) - FLOOR_ACCURACY**2 * np.mean(floor[:, a:b] ** 2)
                  for a, b in itertools.pairwise(edges)])
    if n_blocks == N_BLOCKS and int(np.sum(d > 0)) >= SIGN_MIN:
        return float("inf")
    sd = float(np.std(d, ddof=1))
    if sd == 0:
        return float(np.sign(d.sum()) * np.inf) if d.any() else 0.0
    return float(np.mean(d) / (sd / np.sqrt(len(d))))


def band_t(r: np.ndarray, floor: np.ndarray, rows: np.ndarray, dt: float, sigma: float) -> tuple[float, dict]:
    """The per-band test: the largest t, over octave bands below the kernel's cut-off, of mean(P_b,s(r) −
    K²·P_b,s(floor)) over segments s (Welch: Hann, BAND_SEGMENT_S long, half overlap; the segments, not the
    frequencies, are the units), scaled to the one-sided BAND_P / n_bands point of Student's t (t > 1: above the
    floor in that band). ``r``: the residual on the whole grid, ``floor``: (draws, grid) floor draws, ``rows``: the
    usable rows (the rest is set to 0). A mismatch at low frequency, where the sensors put almost nothing (the floor
    grows as f⁴ through two differentiations), is diluted in the time-domain test by the floor's high-frequency
    power; here it meets only the floor of its own band. Also returns the band of the largest excess."""
    from scipy.stats import t as student

    seg = int(2 ** np.round(np.log2(BAND_SEGMENT_S / dt)))
    starts = list(range(0, len(r) - seg + 1, seg // 2))
    starts = [a for a in starts if rows[a : a + seg].mean() >= 0.5]
    if len(starts) < BAND_MIN_SEGMENTS:
        return 0.0, {}
    w = np.hanning(seg)
    f = np.fft.rfftfreq(seg, dt)
    hi = 1.0 / (2.0 * np.pi * sigma)  # the kernel passes e^(−1/2) of the amplitude here; above, the floor is less sure
    lo = 2.0 / (seg * dt)
    edges = lo * 2.0 ** np.arange(0, np.ceil(np.log2(hi / lo)) + 1)
    edges[-1] = hi

    def power(x: np.ndarray) -> np.ndarray:  # (segments, frequencies)
        xs = np.array([np.where(rows[a : a + seg], x[a : a + seg], 0.0) for a in starts])
        return np.abs(np.fft.rfft((xs - xs.mean(axis=1, keepdims=True)) * w, axis=1)) ** 2

    pr = power(r)
    pf = np.mean([power(d) for d in floor], axis=0)
    n_bands = len(edges) - 1
    crit = float(student.ppf(1.0 - BAND_P / n_bands, len(starts) - 1))
    best, where = -np.inf, {}
    for a, b in itertools.pairwise(edges):
        m = (f >= a) & (f < b)
        if not m.any():
            continue
        d = pr[:, m].sum(axis=1) - FLOOR_ACCURACY**2 * pf[:, m].sum(axis=1)
        sd = float(np.std(d, ddof=1))
        t = float(np.mean(d) / (sd / np.sqrt(len(d)))) if sd > 0 else 0.0
        if t / crit > best:
            best = t / crit
            where = {"band_hz": [float(a), float(b)], "t": t, "t_crit": crit,
                     "power_ratio": float(pr[:, m].sum() / max(pf[:, m].sum(), 1e-300))}
    return float(best), where


def above_floor(ctx: Context, em, y: np.ndarray, seed: int = 0) -> bool:
    """Whether the residual ``y`` (on the grid) of the equation model ``em`` exceeds its noise floor: the time-block
    test (block_t) or the per-band test (band_t) — the test of the `consistent` and `explained` verdicts."""
    rows = em.row_mask
    if rows.sum() < MIN_ROWS:
        return False
    full = noise.draws(ctx, em.equation, seed=seed)
    if block_t(y[rows], full[:, rows]) > T_CRIT:
        return True
    return band_t(y, full, rows, ctx.prep.dt, ctx.states(em.equation).filt.sigma)[0] > 1.0


def excess_removed(ms_nominal: float, ms_augmented: float, ms_floor: float) -> float:
    """The share of the nominal residual's excess over the noise floor (in mean square) that the effects remove."""
    excess_nom = ms_nominal - ms_floor
    return 1.0 - max(ms_augmented - ms_floor, 0.0) / excess_nom if excess_nom > 0 else 0.0


def removes_excess(ctx: Context, em, y_nominal: np.ndarray, y_augmented: np.ndarray, seed: int = 0) -> float:
    """excess_removed for the residuals (on the grid) of the equation model ``em``, its floor drawn as ``assess``."""
    rows = em.row_mask
    floor = noise.draws(ctx, em.equation, seed=seed)[:, rows]
    return excess_removed(float(np.mean(y_nominal[rows] ** 2)), float(np.mean(y_augmented[rows] ** 2)),
                          float(np.mean(floor**2)))


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def assess(ctx: Context, ems: dict, res: dict, seed: int = 0, found: list | None = None,
           moved: list[dict] | None = None) -> dict[str, EquationVerdict]:
    """The verdict of each equation from the final ``res`` (stages.findings.EquationResult) and its models ``ems``; ``found``
    (stages.findings.Found): every effect reported, including those of the window stages and the free decay, which are not
    in the equation's regression (its augmented residual does not hold them); ``moved``: the effects the gate moved
    out (gate.run), whose band test (``band``) is the signature of a compliance or mode (``mode_cause``)."""
    out: dict[str, EquationVerdict] = {}
    remaining: dict[str, Remaining] = {}
    for eq, r in res.items():
        em = ems[eq]
        rows = em.row_mask
        effects = tuple(dict.fromkeys([*r.selected.spec.effects, *(f.name for f in found or [] if f.equation == eq)]))
        if rows.sum() < MIN_ROWS:
            out[eq] = EquationVerdict(eq, "not_assessed", float("nan"), float("nan"), float("nan"),
                                      reason=f"{int(rows.sum())} usable samples, at least {MIN_ROWS} needed",
                                      effects=effects)
            continue
        scale = torque_scale(ctx, eq, rows)
        y_nom = em.target(em.spec0())
        y_aug = em.residual(r.selected.spec, r.selected.fit.coef) if r.selected.spec.effects else y_nom
        full = noise.draws(ctx, eq, seed=seed)
        floor = full[:, rows]
        t_nom, t_aug = block_t(y_nom[rows], floor), block_t(y_aug[rows], floor)
        sigma = ctx.states(eq).filt.sigma
        (b_nom, band_nom), (b_aug, band_aug) = (band_t(y, full, rows, ctx.prep.dt, sigma) for y in (y_nom, y_aug))
        if b_nom > 1.0:  # above the floor in one band: not within it, whatever the time-domain test says
            t_nom = max(t_nom, float("inf"))
        if b_aug > 1.0:
            t_aug = max(t_aug, float("inf"))
        ms_floor = float(np.mean(floor**2))
        v = EquationVerdict(eq, "", _rms(y_nom[rows]) / scale, _rms(y_aug[rows]) / scale, np.sqrt(ms_floor) / scale,
                            t_nom, t_aug, effects=effects, band_nominal=band_nom, band_augmented=band_aug)
        removed = excess_removed(v.residual_nominal**2, v.residual_augmented**2, v.noise_floor**2)
        if t_nom <= T_CRIT and not effects:
            v.verdict = "consistent"
        elif effects and t_aug <= T_CRIT:  # effects selected are significant (select.py) even when the size is not
            v.verdict = "explained"
        elif effects and removed >= PARTLY:
            v.verdict = "partly_explained"
        else:
            v.verdict = "unexplained"
        remaining[eq] = (y_aug, rows, ms_floor, floor)
        out[eq] = v
    detect: dict = {}
    causes = possible_causes(ctx, remaining, detect) if remaining else []
    modes = {eq: mode_cause(eq, [m for m in moved or [] if m.get("equation") == eq and "band" in m]) for eq in out}
    for eq, v in out.items():
        mine = [c for c in causes if c["removes_where_it_acts"].get(eq, 0.0) >= CAUSE_REMOVES]
        if modes[eq] is not None:
            mine = [modes[eq], *mine]
        if mine and v.verdict in ("consistent", "explained"):
            # a plant-parameter or sensor signature is in the residual beyond chance: more specific than the
            # variance test, so the residual is not sensor noise alone even when its size is within the floor's
            v.verdict = "unexplained" if v.verdict == "consistent" else "partly_explained"
            v.reason = (f"its size is within the noise floor, but {mine[0]['value']}" if mine[0]["key"] == "mode" else
                        f"its size is within the noise floor, but it follows the signature of {mine[0]['cause']} "
                        f"(t = {abs(mine[0]['coefficient']) / mine[0]['se']:.0f}, removes "
                        f"{100 * mine[0]['removes_where_it_acts'][eq]:.0f} % of it where that signature is)")
        if v.verdict == "consistent":  # what the recording could have seen: consistent within that, not beyond
            v.detectable = {k: d["smallest_change"] for k, d in detect.items() if d["share"].get(eq, 0.0) >= 0.1}
        if v.verdict in ("partly_explained", "unexplained"):
            y_aug, rows, _, _ = remaining[eq]
            v.remainder = locate(ctx, eq, y_aug, rows)
            excess = max(v.residual_augmented**2 - v.noise_floor**2, 0.0)
            removed = excess_removed(v.residual_nominal**2, v.residual_augmented**2, v.noise_floor**2)
            v.unexplained = {"share": float(np.sqrt(excess)), "removed_by_effects": removed if v.effects else 0.0,
                             "where": where(v.remainder), "signature": signature(ctx, y_aug, rows, eq),
                             "possible_causes": [c for c in [modes[eq]] if c is not None]
                             + [c for c in causes if c["removes"].get(eq, 0.0) > 0]}
    return out


def mode_cause(eq: str, band: list[dict]) -> dict | None:
    """The possible cause "an unmodelled compliance or mode" of an equation whose effects' fitted values depend on the
    frequency band (gate.band_check: no parameter of eq. 4 nor any library effect does): first among the causes, since
    a plant parameter's signature is band-free too. None without such evidence."""
    if not band:
        return None
    b = band[0]["band"]
    text = (f"the fitted {band[0]['name']} ({b['param']}) depends on the frequency band ({b['value']:.4g} ± {b['se']:.2g} "
            f"with the {1000 * b['sigma']:.0f} ms kernel, {b['value_wide']:.4g} ± {b['se_wide']:.2g} with the "
            f"{1000 * b['sigma_wide']:.0f} ms one): the {eq} equation holds dynamics outside eq. 4 — a compliance "
            "(a flexible coupling, belt or shaft) or a structural mode; a frequency response or a step with a fast "
            "encoder on the motor side would show it")
    return {"cause": "an unmodelled compliance or mode", "key": "mode", "value": text, "coefficient": None, "se": None,
            "removes": {eq: 0.0}, "removes_where_it_acts": {eq: 0.0}, "removes_total": None,
            "effects_moved": [m["name"] for m in band], "indistinguishable_from_first": True,
            "short": f"its fitted {', '.join(m['name'] for m in band)} depend on the frequency band"}


# ------------------------------------------------------------------------------ where
def where(loc: Location) -> list[str]:
    """Sentences: the signals the remainder follows, the regions and the times where it is largest."""
    out = []
    top = sorted(((k, c) for k, c in loc.correlations.items() if k != "1"), key=lambda kv: -abs(kv[1]))[:3]
    if top:
        out.append("follows " + ", ".join(f"{k} (r = {c:+.2f})" for k, c in top))
    bias = loc.correlations.get("1", 0.0)
    if abs(bias) > 0.5:
        out.append(f"a constant bias ({100 * abs(bias):.0f} % of its rms)")
    hot = [f"{k} (×{v:.1f} rms)" for k, v in loc.regions.items() if v > 1.3]
    if hot:
        out.append("largest at " + ", ".join(hot))
    if loc.times:
        out.append("worst at t = " + ", ".join(f"{a:.1f}–{b:.1f} s" for a, b in loc.times[:3]))
    return out


def _psd(x: np.ndarray, dt: float, seg: int) -> tuple[np.ndarray, np.ndarray]:
    """Welch periodogram (Hann, half overlap) of ``x``."""
    seg = min(seg, len(x))
    w = np.hanning(seg)
    starts = range(0, len(x) - seg + 1, max(seg // 2, 1))
    p = np.mean([np.abs(np.fft.rfft((x[s : s + seg] - x[s : s + seg].mean()) * w)) ** 2 for s in starts], axis=0)
    return np.fft.rfftfreq(seg, dt), p


def signature(ctx: Context, y: np.ndarray, rows: np.ndarray, eq: str) -> dict:
    """The remainder's frequency band against the data's: its spectral peak, the band holding half its power, and
    how narrow the peak is (peak power over the median of its neighbourhood)."""
    dt = ctx.prep.dt
    seg = int(2 ** np.floor(np.log2(max(64, min(len(y), round(8.0 / dt))))))
    r = np.where(rows, y, 0.0)
    f, p = _psd(r, dt, seg)
    s = ctx.states(eq)
    data = s.theta_ddot if eq == PEND else s.phi_ddot
    _, pd = _psd(np.where(rows, data, 0.0), dt, seg)
    band = (f > 0.05) & (f < 0.5 / (np.pi * s.filt.sigma) * 2)  # below the kernel's cut-off
    if not band.any() or p[band].sum() == 0:
        return {}
    i = np.flatnonzero(band)[int(np.argmax(p[band]))]
    c = np.cumsum(p[band]) / p[band].sum()
    fb = f[band]
    lo, hi = float(fb[np.searchsorted(c, 0.25)]), float(fb[min(np.searchsorted(c, 0.75), len(fb) - 1)])
    near = p[max(0, i - 8) : i + 9]
    narrow = float(p[i] / (np.median(near) or 1.0))
    ratio = p[band] / np.maximum(pd[band] / pd[band].sum() * p[band].sum(), 1e-300)
    return {"peak_hz": float(f[i]), "band_hz": [lo, hi], "peak_narrowness": narrow,
            "data_peak_hz": float(f[band][int(np.argmax(pd[band]))]),
            "largest_excess_over_data_hz": float(fb[int(np.argmax(ratio))])}


# ------------------------------------------------------------------------------ possible causes
def _id_pair(ctx: Context, s: States, plant: FurutaPlant, eq: str, theta_gain: float = 1.0, theta_sign: float = 1.0,
             phi_sign: float = 1.0) -> np.ndarray:
    g = theta_gain * theta_sign
    tp, ta = plant.inverse_dynamics(g * (s.theta - ctx.model.theta_offset), g * s.theta_dot, phi_sign * s.phi_dot,
                                    g * s.theta_ddot, phi_sign * s.phi_ddot)
    return ta if eq == ARM else tp


Columns = Callable[[float], dict[str, np.ndarray]]


def cause_columns(ctx: Context, equations: list[str]) -> list[tuple[str, str, Columns]]:
    """(key, name, columns) per possible cause; ``columns(a)`` gives per equation the column X with residual ≈ a·X.

    A plant parameter p of the config's parametrisation (true value p·(1 − a)) and a θ sensor scale (θ read as
    θ_true/(1 − a)) enter eq. 4 nonlinearly (α = J_p + M l², …): X(a) = (ID at the changed value − ID)/(−a), the secant
    (the derivative at a → 0), so that the fit, iterated, is exact for a change of any size. A reversed sign of θ or φ
    is the column ID(reversed) − ID, with coefficient −1 when reversed.

    The columns are computed on the noise-reduced signals of the noise floor (furuta_rt.diagnose.judgement.noise.smoothed):
    on the measured ones they would share the residual's own noise (α·δθ̈ is in both the residual and the inertia
    column)."""
    out: list[tuple[str, str, Columns]] = []
    plant = ctx.plant
    clean = noise.smoothed(ctx.prep, ctx)
    st = {eq: clean.states(ctx.states(eq).filt.sigma) for eq in equations}
    base = {eq: _id_pair(ctx, st[eq], plant, eq) for eq in equations}

    def secant(id_at: Callable[[float], dict[str, np.ndarray]]) -> Columns:
        def columns(a: float) -> dict[str, np.ndarray]:
            a = a if abs(a) >= STEP else STEP
            moved = id_at(1.0 - a)
            return {eq: (moved[eq] - base[eq]) / -a for eq in equations}
        return columns

    cfg = ctx.rig.plant
    p0 = cfg.lumped()
    for key, name in PLANT_CAUSES.get(cfg.parametrisation, ()):
        value = getattr(cfg, key, None)
        if not value:
            continue

        def plant_at(f: float, key: str = key, value: float = value) -> dict[str, np.ndarray]:
            p1, q = cfg.model_copy(update={key: value * f}).lumped(), plant.p
            moved = FurutaPlant(LumpedParameters(q.alpha + p1.alpha - p0.alpha, q.beta + p1.beta - p0.beta,
                                                 q.gamma + p1.gamma - p0.gamma, q.epsilon + p1.epsilon - p0.epsilon))
            return {eq: _id_pair(ctx, st[eq], moved, eq) for eq in equations}

        try:
            plant_at(1.0 + STEP)
        except ValueError:
            continue
        out.append((key, name, secant(plant_at)))
    out.append(("theta_scale", "θ sensor scale",
                secant(lambda f: {eq: _id_pair(ctx, st[eq], plant, eq, theta_gain=f) for eq in equations})))
    for key, name, kw in (("theta_sign", "sign of θ", {"theta_sign": -1.0}), ("phi_sign", "sign of φ", {"phi_sign": -1.0})):
        flip = {eq: _id_pair(ctx, st[eq], plant, eq, **kw) - base[eq] for eq in equations}
        out.append((key, name, lambda a, flip=flip: flip))
    if ARM in equations:
        column = compliance_column(ctx)
        comp = {eq: column if eq == ARM else np.zeros_like(column) for eq in equations}
        out.append(("compliance", COMPLIANCE, lambda a, comp=comp: comp))
    return out


COMPLIANCE = "an unmodelled compliance between the motor and the arm"
FIXED_COLUMN_CAUSES = ("theta_sign", "phi_sign", "compliance")
"""Causes whose column does not depend on the coefficient (no secant refit) and that are no change of a rig
parameter (no smallest detectable change)."""


def compliance_column(ctx: Context) -> np.ndarray:
    """The arm residual's column of a compliant motor–arm coupling (a belt, a flexible shaft coupling): the rotor
    (inertia J_m) turns by φ_m = φ + τ_c/k, where τ_c is the torque the spring k passes to the arm, so the command
    also drives J_m·φ̈_m = J_m·φ̈ + (J_m/k)·τ̈_c. The first term is an arm inertia (a library effect, seen below the
    mode); the second is not: with τ_c ≈ τ_command (to first order in J_m/J), the residual ID − τ_command holds
    a·(−τ̈_command) with a = J_m/k = 1/ω_m² > 0, ω_m the rotor's mode on the spring with the arm held. The command
    is measured exactly (no sensor noise shares the residual's), seen through the arm kernel like every column."""
    key = "compliance column"
    if key not in ctx._columns:
        dt = ctx.prep.dt
        ctx._columns[key] = -np.gradient(np.gradient(ctx.command_torque(ctx.base_path), dt), dt)
    return ctx._columns[key]


def possible_causes(ctx: Context, remaining: dict[str, Remaining], detect: dict | None = None) -> list[dict]:
    """Each cause fitted alone to the remaining residuals of both equations jointly (each equation weighted by its
    noise floor; the secant columns refitted at the estimate, twice), with a blocked standard error over time blocks
    (``_block_se``, at least the spread on the noise floor's draws); the significant ones (``CAUSE_T`` standard
    errors, removing ``CAUSE_REMOVES`` of the residual where they act), best first. ``detect``, if given, receives
    per plant-parameter or sensor-scale cause the smallest relative change the recording could have seen
    (CAUSE_T standard errors) and each equation's share of the cause's weight."""
    eqs = list(remaining)
    t = ctx.prep.t
    edges = np.linspace(t[0], t[-1], N_BLOCKS + 1)
    blocks = {eq: np.clip(np.searchsorted(edges, t[rows], side="right") - 1, 0, N_BLOCKS - 1)
              for eq, (_, rows, _, _) in remaining.items()}
    out = []
    for key, name, columns in cause_columns(ctx, eqs):
        a = 0.0
        for _ in range(3):
            cols = columns(a)
            sxy, sxx, syy_b = np.zeros(N_BLOCKS), np.zeros(N_BLOCKS), np.zeros(N_BLOCKS)
            for eq in eqs:
                y, rows, ms_floor, _ = remaining[eq]
                w = 1.0 / max(ms_floor, 1e-300)
                x, yy = cols[eq][rows], y[rows]
                sxy += w * np.bincount(blocks[eq], x * yy, N_BLOCKS)
                sxx += w * np.bincount(blocks[eq], x * x, N_BLOCKS)
                syy_b += w * np.bincount(blocks[eq], yy * yy, N_BLOCKS)
            syy = float(syy_b.sum())
            if sxx.sum() <= 0 or not np.isfinite(sxx.sum()):
                break
            a = float(sxy.sum() / sxx.sum())
            if key in FIXED_COLUMN_CAUSES or not -0.9 < a < 0.9:
                break
        if sxx.sum() <= 0 or not np.isfinite(a):
            continue
        se = max(_block_se(sxy, sxx, a), _null_spread(remaining, cols))
        if detect is not None and key not in FIXED_COLUMN_CAUSES:
            weight = {eq: float(cols[eq][remaining[eq][1]] @ cols[eq][remaining[eq][1]]) / max(remaining[eq][2], 1e-300)
                      for eq in eqs}
            total = sum(weight.values()) or 1.0
            detect[key] = {"cause": name, "smallest_change": CAUSE_T * se,
                           "share": {eq: w / total for eq, w in weight.items()}}
        removes_all = a * a * sxx.sum() / syy if syy > 0 else 0.0
        local = _removes_where_it_acts(a, sxx, syy_b)
        if abs(a) < CAUSE_T * se or local < CAUSE_REMOVES:
            continue
        removes, where = {}, {}
        for eq in eqs:
            y, rows, _, _ = remaining[eq]
            x, yy = cols[eq][rows], y[rows]
            ms = float(np.mean(yy**2))
            removes[eq] = max(0.0, 1.0 - float(np.mean((yy - a * x) ** 2)) / ms) if ms > 0 else 0.0
            r2 = np.bincount(blocks[eq], (yy - a * x) ** 2, N_BLOCKS)
            y2 = np.bincount(blocks[eq], yy**2, N_BLOCKS)
            x2 = np.bincount(blocks[eq], x**2, N_BLOCKS)
            share = np.clip(1.0 - r2 / np.maximum(y2, 1e-300), 0.0, 1.0)
            where[eq] = float(np.sum(x2 / x2.sum() * share)) if x2.sum() > 0 else 0.0
        out.append({"cause": name, "key": key, "value": _cause_value(ctx, key, a, se), "coefficient": a, "se": se,
                    "removes": removes, "removes_where_it_acts": where, "removes_total": float(removes_all),
                    "removes_total_where_it_acts": local})
    # a sign is reversed (coefficient −1) or it is not: a partial fit of a sign column is no cause
    out = [c for c in out if c["key"] not in ("theta_sign", "phi_sign") or abs(c["coefficient"] + 1) <= 0.3]
    # a spring's J_m/k is positive; the other sign is a lag of the actuator (or the sensor noise fed back through the
    # loop: −1 to −7·10⁻⁴ s² on the simulator's sine-excited null cases), no compliance
    out = [c for c in out if c["key"] != "compliance" or c["coefficient"] > 0]
    # a parameter's true value is p·(1 − a) and a θ scale 1/(1 − a): a ≥ 1 is a negative mass, inertia, length or
    # scale, no possible cause (its column only stands in for a sign, an offset or physics outside the list)
    out = [c for c in out if c["key"] in FIXED_COLUMN_CAUSES or c["coefficient"] < 1.0]
    out.sort(key=lambda c: -c["removes_total"])
    for c in out:  # causes that fit (almost) as well as the first are look-alikes the data cannot tell apart
        c["indistinguishable_from_first"] = bool(c["removes_total"] >= out[0]["removes_total"] - LOOKALIKE_MARGIN)
    return out[:4]


def _block_se(sxy: np.ndarray, sxx: np.ndarray, a: float) -> float:
    """The standard error of a = Σ sxy / Σ sxx from the blocks' own scatter about the fit (the linearised blocked
    jackknife, i.e. the cluster-robust sandwich: var = B/(B − 1)·Σ_b (sxy_b − a·sxx_b)² / (Σ sxx)²).

    The delete-one-block jackknife of the ratio is not used: where one block holds most of a column's weight (the
    catch transient at the start of a balancing run holds 97 % of the pendulum-inertia column's), deleting it leaves
    the quiet blocks, whose coefficient is another quantity (there the column is the noise-driven motion of the loop,
    which the residual's noise correlates with through the feedback: +0.4 on every balancing null case), and its
    spread says the cause cannot be seen at all (± 0.66 for a 20 % inertia error the transient measures to ± 0.01)."""
    n = len(sxx)
    return float(np.sqrt(n / (n - 1) * np.sum((sxy - a * sxx) ** 2)) / sxx.sum()) if sxx.sum() > 0 else float("inf")


def _removes_where_it_acts(a: float, sxx: np.ndarray, syy: np.ndarray) -> float:
    """The share of the residual a cause removes in the blocks that carry its signature: the share in each block,
    averaged with the block's share of the column's weight. A cause that acts in a transient of a few seconds (a
    pendulum inertia under balancing: the catch at the start) removes most of the residual there and little of the
    whole, which is mostly sensor noise."""
    if sxx.sum() <= 0:
        return 0.0
    share = np.minimum(a * a * sxx / np.maximum(syy, 1e-300), 1.0)
    return float(np.sum(sxx / sxx.sum() * share))


def _null_spread(remaining: dict[str, Remaining], cols: dict[str, np.ndarray]) -> float:
    """The spread of a cause's coefficient on sensor noise alone: the rms of the coefficients fitted to the noise
    floor's draws (the same weights). The blocked jackknife alone under-states it where the noise has structure
    (the encoder's ramps in slow motion, sticks): on the simulator's null cases it gives |t| up to 7."""
    num = den = 0.0
    coefs = []
    draws = min(len(d) for _, _, _, d in remaining.values())
    for m in range(draws):
        num = den = 0.0
        for eq, (_, rows, ms_floor, floor) in remaining.items():
            x, w = cols[eq][rows], 1.0 / max(ms_floor, 1e-300)
            num += w * float(x @ floor[m])
            den += w * float(x @ x)
        coefs.append(num / den if den > 0 else 0.0)
    return float(np.sqrt(np.mean(np.square(coefs)))) if coefs else 0.0


def _cause_value(ctx: Context, key: str, a: float, se: float) -> str:
    """The cause's size in words: y = ID_config − ID_true ≈ −c·∂ID/∂c for a relative change c of a parameter."""
    if key in ("theta_sign", "phi_sign"):
        angle = "θ" if key == "theta_sign" else "φ"
        return f"{angle} appears reversed relative to the rig (coefficient {a:+.2f} ± {se:.2f}; −1: reversed)"
    if key == "compliance":  # a = J_m/k = 1/ω_m²
        mode = f"with its mode near {1 / (2 * np.pi * np.sqrt(a)):.1f} Hz " if a > 0 else ""
        return f"a rotor-side inertia on a spring {mode}(J_m/k = {a:.2g} ± {se:.2g} s²)"
    if key == "theta_scale":  # the θ read is s × the true θ: y ≈ (1 − 1/s)·∂ID/∂s
        s = 1.0 / (1.0 - a) if a < 1 else float("inf")
        return f"θ reads {s:.3f} × the true angle (± {se:.2g})"
    c = -a
    return f"{key} = {1 + c:.3f} × config (± {se:.2g})"


def with_verdicts(located: str, res: dict, verdicts: dict[str, EquationVerdict]) -> str:
    """The ``located`` text with each equation's sentence restated knowing its verdict (only a `consistent` one says
    so)."""
    for eq, r in res.items():
        if eq in verdicts:
            effects = list(r.selected.spec.effects)
            located = located.replace(describe(r.location, effects), describe(r.location, effects, verdicts[eq].verdict), 1)
    return located


# ------------------------------------------------------------------------------ the summary line
def percent(x: float) -> str:
    """A share as a percentage: one decimal, or two significant digits below 0.1 % (an encoder's noise floor is
    a few hundredths of a percent, which "0.0 %" would hide)."""
    if not np.isfinite(x):
        return "n/a"
    return f"{100 * x:.2g} %" if 0 < abs(x) < 0.001 else f"{100 * x:.1f} %"


def summary(verdicts: dict[str, EquationVerdict]) -> str:
    """One line: each equation's verdict with its numbers; for a remainder, what it follows and the first cause."""
    parts = []
    for eq, v in verdicts.items():
        name = f"{eq} equation"
        if v.verdict == "not_assessed":
            parts.append(f"{name} not assessed ({v.reason})")
            continue
        pct = percent
        if v.verdict == "consistent":
            parts.append(f"{name} consistent with the nominal model (residual {pct(v.residual_nominal)}, noise floor "
                         f"{pct(v.noise_floor)})")
        elif v.verdict == "explained":
            parts.append(f"{name} explained by {', '.join(v.effects)} (residual {pct(v.residual_nominal)} → "
                         f"{pct(v.residual_augmented)}, noise floor {pct(v.noise_floor)})")
        else:
            u = v.unexplained or {}
            by = f" after {', '.join(v.effects)}" if v.effects else ""
            left = (f"{pct(u.get('share', 0.0))} of its torque scale left{by}" if v.residual_augmented > v.noise_floor else
                    f"within the noise floor in size{by}, not in its signature")
            text = (f"{name} {v.verdict.replace('_', ' ')}: {left} "
                    f"(residual {pct(v.residual_nominal)} → {pct(v.residual_augmented)}, noise floor {pct(v.noise_floor)})")
            if v.remainder is not None:
                top = sorted(((k, c) for k, c in v.remainder.correlations.items() if k != "1"), key=lambda kv: -abs(kv[1]))
                if top:
                    text += f", follows {top[0][0]}"
            causes = u.get("possible_causes") or []
            if causes:
                alike = [c for c in causes[1:] if c.get("indistinguishable_from_first")]
                text += f" — {causes[0]['cause']}: {causes[0].get('short', causes[0]['value'])}"
                text += "".join(f" or {c['cause']}: {c.get('short', c['value'])}" for c in alike[:1]) + "?"
            parts.append(text)
    return "; ".join(parts)
