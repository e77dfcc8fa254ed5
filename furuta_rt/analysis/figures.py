"""The thesis' figures 9 and 11–16 redrawn from our analyses and simulations (matplotlib, Agg canvas;
no pyplot state, so importing this module changes no global backend)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from furuta_rt.analysis.describing_function import LimitCycleAnalysis
from furuta_rt.analysis.periodic_orbit import PeriodicOrbit, Trajectory
from furuta_rt.recording import Recording

DPI = 80
MIN_WIDTH_PX = 1000  # every figure at least this wide (the dpi is raised for small ones)


def _new(rows: int, cols: int, size: tuple[float, float]) -> tuple[Figure, np.ndarray]:
    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False))
    return fig, axes


def _save(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=max(DPI, MIN_WIDTH_PX / fig.get_figwidth()))
    return path


G_NAME = "G(s) = φ̇(s)/F(s), arm friction torque F → arm velocity φ̇"
G_UNIT = "rad/s per N m"


def nyquist_axes(ax: Axes, lc: LimitCycleAnalysis, title: str) -> None:
    """G(jω) for ω > 0 (solid) and ω < 0 (dashed), the −1/N(C) locus (the negative real axis) and
    the describing-function solutions (G: section 4's transfer function from the friction torque on the
    arm to φ̇, for the given feedback)."""
    w = np.logspace(-3, 4, 40000)
    g = np.asarray(lc.G(1j * w), dtype=complex)
    g0 = complex(lc.G(1e-9j))
    sizes = [1.5 * abs(re) for _, re in lc.crossings] + [float(np.percentile(np.abs(g), 50)), 1e-3]
    if np.isfinite(g0) and abs(g0) < 1e6:
        sizes.append(1.2 * abs(g0))
    lim = max(sizes)
    g_clip = np.where(np.abs(g) < 20 * lim, g, np.nan)
    ax.plot(g_clip.real, g_clip.imag, "C0", lw=1.2, label="G(jω), ω > 0")
    ax.plot(g_clip.real, -g_clip.imag, "C0--", lw=0.8, label="ω < 0")
    ax.plot([-10 * lim, 0], [0, 0], "C3", lw=2.5, alpha=0.5, label="−1/N(C) = −πC/(4Fc)")
    for p in lc.predictions:
        ax.plot(p.g_real, 0.0, "ko" if p.stable else "kx", ms=7)
        ax.annotate(f"ω={p.omega:.2f} rad/s\n{'stable' if p.stable else 'unstable'} LC", (p.g_real, 0.0),
                    textcoords="offset points", xytext=(5, 8), fontsize=7)
    ax.axhline(0, color="0.7", lw=0.5)
    ax.axvline(0, color="0.7", lw=0.5)
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel(f"Re G(jω) ({G_UNIT})")
    ax.set_ylabel(f"Im G(jω) ({G_UNIT})")


def nyquist_figure(cases: Sequence[tuple[str, LimitCycleAnalysis]], path: Path) -> Path:
    """Figure 9: Nyquist plots of G(s) from friction torque to φ̇ for several feedbacks."""
    n = len(cases)
    cols = 2 if n > 1 else 1
    rows = (n + cols - 1) // cols
    fig, axes = _new(rows, cols, (6.0 * cols, 5.2 * rows))
    fig.suptitle(f"Nyquist plot of {G_NAME}\nwith −1/N(C), the Coulomb describing function's locus", fontsize=10)
    for ax, (title, lc) in zip(axes.flat, cases, strict=False):
        nyquist_axes(ax, lc, title)
    axes.flat[0].legend(fontsize=7, loc="lower left")
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    return _save(fig, path)


def feedback_figure(cases: Sequence[tuple[str, Trajectory]], path: Path) -> Path:
    """Figure 11: θ and φ of the nonlinear loop with Coulomb friction for several feedbacks."""
    fig, axes = _new(len(cases), 2, (9.0, 2.3 * len(cases)))
    for row, (title, tr) in zip(axes, cases, strict=True):
        row[0].plot(tr.t, tr.x[:, 0], lw=0.8)
        row[0].set_ylabel("θ (rad)")
        row[1].plot(tr.t, tr.x[:, 2], lw=0.8)
        row[1].set_ylabel("φ (rad)")
        row[0].set_title(title, fontsize=9, loc="left")
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    return _save(fig, path)


def states_figure(rec: Recording, path: Path, title: str) -> Path:
    """Figure 12: the four states as the controller sees them (θ_f, φ, θ̇_f, φ̂̇)."""
    fig, axes = _new(2, 2, (9.0, 5.0))
    cols = [("θ (rad)", rec.theta), ("φ (rad)", rec.phi), ("θ̇ (rad/s)", rec.theta_dot),
            ("φ̇ estimate (rad/s)", rec.extra["phi_dot_hat"])]
    for ax, (label, y) in zip(axes.flat, cols, strict=True):
        ax.plot(rec.t, y, lw=0.7)
        ax.set_ylabel(label)
        ax.set_xlabel("t (s)")
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def friction_figure(rec: Recording, path: Path, title: str) -> Path:
    """Figure 13: θ, θ̇; φ, φ̇; the control signal u and the resulting torque u_r = u − F (F the
    friction force, so u_r = u + friction torque)."""
    fig, axes = _new(3, 1, (8.0, 7.0))
    t = rec.t
    ax = axes[0, 0]
    ax.plot(t, rec.extra["true_theta"], lw=0.8, label="θ (rad)")
    ax2 = ax.twinx()
    ax2.plot(t, rec.extra["true_theta_dot"], "C1", lw=0.6, label="θ̇ (rad/s)")
    ax.set_ylabel("θ (rad)")
    ax2.set_ylabel("θ̇ (rad/s)", color="C1")
    ax = axes[1, 0]
    ax.plot(t, rec.extra["true_phi"], lw=0.8)
    ax2 = ax.twinx()
    ax2.plot(t, rec.extra["true_phi_dot"], "C1", lw=0.6)
    ax.set_ylabel("φ (rad)")
    ax2.set_ylabel("φ̇ (rad/s)", color="C1")
    ax = axes[2, 0]
    ax.plot(t, rec.u, lw=0.8, label="u")
    ax.plot(t, rec.u + rec.extra["friction"], lw=0.8, label="u_r = u − F")
    ax.set_ylabel("N m")
    ax.set_xlabel("t (s)")
    ax.legend(fontsize=7)
    axes[0, 0].set_title(title, fontsize=9)
    return _save(fig, path)


def comparison_figure(rec: Recording, thesis_std: tuple[float, float], path: Path, title: str) -> Path:
    """Figure 14 (simulation half): θ and φ with the thesis' measured ±std and ±√2·std (the amplitude
    of a sine with that std) marked, on the thesis' scale."""
    fig, axes = _new(2, 1, (8.0, 5.0))
    for ax, y, s, label in ((axes[0, 0], rec.theta, thesis_std[0], "θ (rad)"), (axes[1, 0], rec.phi, thesis_std[1], "φ (rad)")):
        ax.plot(rec.t, y, lw=0.8, label=f"simulation (std {np.std(y):.3g})")
        for k, style in ((1.0, ":"), (np.sqrt(2.0), "--")):
            ax.axhline(np.mean(y) + k * s, color="C3", ls=style, lw=0.8)
            ax.axhline(np.mean(y) - k * s, color="C3", ls=style, lw=0.8)
        ax.plot([], [], "C3:", label=f"thesis ±std = ±{s:g}")
        ax.plot([], [], "C3--", label="thesis ±√2·std")
        ax.set_ylabel(label)
        ax.legend(fontsize=7, loc="upper right")
    axes[1, 0].set_xlabel("t (s)")
    axes[0, 0].set_title(title, fontsize=9)
    return _save(fig, path)


def compensation_figure(recs: Sequence[tuple[str, Recording]], path: Path) -> Path:
    """Figure 15: θ and φ with each friction compensation."""
    fig, axes = _new(len(recs), 2, (9.0, 2.3 * len(recs)))
    for row, (title, rec) in zip(axes, recs, strict=True):
        row[0].plot(rec.t, rec.theta, lw=0.7)
        row[0].set_ylabel("θ (rad)")
        row[1].plot(rec.t, rec.phi, lw=0.7)
        row[1].set_ylabel("φ (rad)")
        row[0].set_title(f"{title}: std θ {np.std(rec.theta):.2g}, std φ {np.std(rec.phi):.2g}", fontsize=9, loc="left")
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    return _save(fig, path)


def orbit_figure(orbit: PeriodicOrbit, sim: Trajectory, df_omega: float | None, df_amp_phidot: float | None,
                 path: Path, title: str) -> Path:
    """The limit cycle three ways: periodic orbit (shooting), long simulation (last periods) and the
    describing function's sine, in the (φ, φ̇) and (θ, θ̇) planes and φ̇(t) over one period."""
    fig, axes = _new(1, 3, (12.0, 3.8))
    tr = orbit.trajectory
    n = len(tr.t)
    tail = sim.x[-3 * n:]
    for ax, (i, j, xl, yl) in zip(axes[0, :2], ((2, 3, "φ (rad)", "φ̇ (rad/s)"), (0, 1, "θ (rad)", "θ̇ (rad/s)")), strict=True):
        ax.plot(tail[:, i], tail[:, j], color="0.6", lw=3, label="long simulation")
        ax.plot(tr.x[:, i], tr.x[:, j], "C0", lw=1, label="periodic orbit")
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
    if df_omega and df_amp_phidot:
        a = np.linspace(0, 2 * np.pi, 200)
        axes[0, 0].plot(df_amp_phidot / df_omega * np.sin(a), df_amp_phidot * np.cos(a), "C3--", lw=1,
                        label="describing function")
        # the sine's upward zero crossing aligned with the orbit's breakaway in the positive direction
        up = np.nonzero((tr.x[:-1, 3] <= 0.0) & (tr.x[1:, 3] > 0.0))[0]
        t_up = float(tr.t[up[0]] - tr.t[0]) if len(up) else 0.0
        t1 = np.linspace(0, tr.t[-1] - tr.t[0], 400)
        axes[0, 2].plot(t1, df_amp_phidot * np.sin(df_omega * (t1 - t_up)), "C3--", lw=1, label="describing function")
    axes[0, 2].plot(tr.t - tr.t[0], tr.x[:, 3], "C0", lw=1, label="periodic orbit")
    axes[0, 2].set_xlabel("t (s) from the θ = 0 crossing")
    axes[0, 2].set_ylabel("φ̇ (rad/s)")
    axes[0, 0].legend(fontsize=7)
    axes[0, 2].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)
