"""What the control process hands to the logger: the tick record layout (kept import-light, so the
logger process starts without loading the controller's dependencies)."""

from __future__ import annotations

STATE_NAMES: tuple[str, ...] = ("idle", "armed", "balancing", "tripped", "calibrating", "swinging_up")
"""Supervisor state index → name, as logged in /furuta/tick ``state``."""

TICK_RECORD: tuple[str, ...] = (
    "wall_ns", "dev_ns", "seq", "t", "theta_adc", "theta_dot_adc", "phi_count", "status",
    "theta", "theta_dot", "phi", "phi_dot_hat", "u", "u_lin", "u_comp", "saturated", "state", "reset",
    "period_us", "read_us", "update_us", "write_us", "latency_us", "lateness_us",
    "overruns", "seq_gaps", "crc_errors", "dropped", "fc_hat",
)  # fmt: skip
"""Field order of the tuples the loop sends to the logger (``state`` is an index into STATE_NAMES; ``fc_hat``:
the Coulomb level the compensator uses, the online estimate with ``--comp adaptive``)."""
