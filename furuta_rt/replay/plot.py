"""Plots of a recording (θ, φ, u, estimated φ̇), with the replayed controller's u and φ̂̇ when given."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from furuta_rt.errors import UserError
from furuta_rt.recording import Recording


def plot_recording(
    rec: Recording,
    path: str | Path,
    *,
    u_replayed: np.ndarray | None = None,
    phi_dot_replayed: np.ndarray | None = None,
    title: str = "",
    u_unit: str = "N m",
) -> Path:
    """Four panels against t: θ, φ, u (logged, and replayed), φ̇ (logged estimate or dφ/dt, and replayed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = rec.t
    phi_dot = rec.extra.get("phi_dot_hat")
    phi_dot_label = "φ̂̇ logged"
    if phi_dot is None:
        phi_dot, phi_dot_label = np.gradient(rec.phi, t), "dφ/dt"
    fig, axes = plt.subplots(4, 1, sharex=True, figsize=(10, 9), constrained_layout=True)
    axes[0].plot(t, rec.theta, lw=0.8)
    axes[0].set_ylabel("θ (rad)")
    axes[1].plot(t, rec.phi, lw=0.8)
    axes[1].set_ylabel("φ (rad)")
    axes[2].plot(t, rec.u, lw=0.8, label="u logged")
    if u_replayed is not None:
        axes[2].plot(t, u_replayed, lw=0.8, ls="--", label="u replayed")
        axes[2].legend(loc="upper right")
    axes[2].set_ylabel(f"u ({u_unit})")
    axes[3].plot(t, phi_dot, lw=0.8, label=phi_dot_label)
    if phi_dot_replayed is not None:
        axes[3].plot(t, phi_dot_replayed, lw=0.8, ls="--", label="φ̂̇ replayed")
    axes[3].legend(loc="upper right")
    axes[3].set_ylabel("φ̇ (rad/s)")
    axes[3].set_xlabel("t (s)")
    for ax in axes:
        ax.grid(True, lw=0.3)
    if title:
        fig.suptitle(title)
    p = Path(path)
    try:
        fig.savefig(p, dpi=110)
    except (OSError, ValueError) as err:
        raise UserError(f"cannot write plot {p}: {err}") from None
    finally:
        plt.close(fig)
    return p
