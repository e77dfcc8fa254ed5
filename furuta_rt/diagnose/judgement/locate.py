"""Where the mismatch lives: which equation, which operating regions, which times.

Works on the inverse-dynamics residuals of the nominal model (furuta_rt.diagnose.regression.library), so it is the
same for an unstable plant under feedback and for open-loop data: each equation's residual is compared
with the torque scale of that equation, correlated with the signals that name physics (sgn φ̇, φ̇, φ,
u, u̇ — the command torque and its rate, θ, θ̇, θ̈, φ̈, φ̇², sin θ cos θ φ̇², sgn θ̇), split by operating region (arm reversals / low
|φ̇|, large |u|), and its largest stretches are listed in time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from furuta_rt.diagnose.regression.library import ARM, Context


@dataclass
class Location:
    equation: str
    relative_rms: float  # residual rms / the equation's torque scale
    correlations: dict[str, float]
    regions: dict[str, float]  # rms in region / rms elsewhere
    times: list[tuple[float, float]]
    text: str = ""
    extra: dict[str, float] = field(default_factory=dict)


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    sa, sb = np.std(a), np.std(b)
    if sa == 0 or sb == 0:
        return 0.0
    return float(np.mean((a - a.mean()) * (b - b.mean())) / (sa * sb))


def _intervals(t: np.ndarray, flag: np.ndarray, min_gap: float) -> list[tuple[float, float]]:
    if not flag.any():
        return []
    idx = np.flatnonzero(flag)
    out = [[t[idx[0]], t[idx[0]]]]
    for i in idx[1:]:
        if t[i] - out[-1][1] > min_gap:
            out.append([t[i], t[i]])
        else:
            out[-1][1] = t[i]
    return [(float(a), float(b)) for a, b in out]


def features(ctx: Context, equation: str) -> dict[str, np.ndarray]:
    """The signals a residual is compared with (u: the command torque, seen through the same filter)."""
    s, f = ctx.states(equation), ctx.fine
    command = ctx.command_torque(ctx.base_path)
    return {
        "sgn(φ̇)": np.sign(f.phi_dot), "φ̇": s.phi_dot, "φ": s.phi, "u": command,
        "u̇": np.gradient(command, ctx.prep.dt), "φ̈": s.phi_ddot, "θ": s.theta, "θ̇": s.theta_dot,
        "θ̈": s.theta_ddot, "φ̇²": s.phi_dot**2, "sin θ cos θ φ̇²": np.sin(s.theta) * np.cos(s.theta) * s.phi_dot**2,
        "sgn(θ̇)": np.sign(f.theta_dot), "1": np.ones_like(s.theta),
    }


def torque_scale(ctx: Context, equation: str, rows: np.ndarray) -> float:
    """The equation's torque scale (rms on ``rows``): the command torque (arm), the gravity torque ε sin θ (pendulum)."""
    if equation == ARM:
        scale = float(np.sqrt(np.mean(ctx.command_torque(ctx.base_path)[rows] ** 2)))
    else:
        scale = float(np.sqrt(np.mean((ctx.plant.p.epsilon * np.sin(ctx.states(equation).theta))[rows] ** 2)))
    return scale or 1.0


def locate(ctx: Context, equation: str, y: np.ndarray, rows: np.ndarray) -> Location:
    """Describe the nominal residual ``y`` of ``equation`` on ``rows``."""
    if rows.sum() < 50:
        return Location(equation, float("nan"), {}, {}, [], text="too few usable samples")
    f = ctx.fine
    r = y[rows]
    feats = features(ctx, equation)
    command = feats["u"]
    scale = torque_scale(ctx, equation, rows)
    corr = {k: (_corr(r, v[rows]) if k != "1" else float(np.mean(r) / (np.sqrt(np.mean(r**2)) or 1.0))) for k, v in feats.items()}
    rms = float(np.sqrt(np.mean(r**2)))
    regions = {}
    speed = np.abs(f.phi_dot)
    low = speed < max(0.1, float(np.quantile(speed[ctx.prep.valid], 0.2)))
    reversal = np.zeros_like(low)
    sgn = np.sign(f.phi_dot)
    flips = np.flatnonzero(np.diff(sgn) != 0)
    w = max(1, round(0.05 / ctx.prep.dt))
    for i in flips:
        reversal[max(0, i - w) : i + w] = True
    big_u = np.abs(command) > np.quantile(np.abs(command[rows]), 0.8)
    for name, m in (("arm reversals", reversal), ("low |φ̇|", low), ("large |u|", big_u)):
        a, b = rows & m, rows & ~m
        if a.sum() > 50 and b.sum() > 50:
            regions[name] = float(np.sqrt(np.mean(y[a] ** 2)) / (np.sqrt(np.mean(y[b] ** 2)) or 1.0))
    # times: 1 s rolling rms above twice its median
    t = ctx.prep.t
    win = max(1, round(1.0 / ctx.prep.dt))
    yy = np.where(rows, y, 0.0) ** 2
    cnt = np.convolve(rows.astype(float), np.ones(win), mode="same")
    roll = np.sqrt(np.convolve(yy, np.ones(win), mode="same") / np.maximum(cnt, 1))
    med = float(np.median(roll[rows])) if rows.any() else 0.0
    times = _intervals(t, rows & (roll > 2 * med) & (cnt > 0.5 * win), 1.0) if med > 0 else []
    return Location(equation, rms / scale, corr, regions, times[:5])


def describe(loc: Location, selected: list[str], verdict: str | None = None) -> str:
    """One sentence for one equation. It says "consistent" only when the verdict (furuta_rt.diagnose.judgement.verdict) is:
    no effect selected is not an all-clear."""
    eq = "arm equation" if loc.equation == ARM else "pendulum equation"
    if loc.text:
        return f"{eq}: {loc.text}"
    if not selected and verdict == "consistent":
        return f"{eq}: consistent with the nominal model (residual {100 * loc.relative_rms:.1f} % of its torque scale)"
    top = sorted(((k, v) for k, v in loc.correlations.items() if k != "1"), key=lambda kv: -abs(kv[1]))[:2]
    none = "" if selected else "no library effect selected; "
    parts = [f"{eq}: {none}residual {100 * loc.relative_rms:.1f} % of its torque scale"]
    bias = loc.correlations.get("1", 0.0)
    if abs(bias) > 0.5:
        parts.append(f"a constant bias ({100 * abs(bias):.0f} % of its rms)")
    parts.append("follows " + ", ".join(f"{k} (r = {v:+.2f})" for k, v in top))
    hot = [f"{k} (×{v:.1f} rms)" for k, v in loc.regions.items() if v > 1.3]
    if hot:
        parts.append("largest at " + ", ".join(hot))
    if loc.times:
        parts.append("worst at t = " + ", ".join(f"{a:.1f}–{b:.1f} s" for a, b in loc.times[:3]))
    return "; ".join(parts)
