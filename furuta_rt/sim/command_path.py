"""The one latency rule of every simulated loop: when the command answering a sample reaches the actuator.

The command computed from the sample of tick k acts from t_k + command_delay_ticks·h, then through the actuator's own
``input_delay``; a rig with the ``command_latency`` effect states the whole lag instead (the simulator's delay line
carries it, the command set at the sample instant). The same rule is what the diagnosis assumes of a recording
(furuta_rt.diagnose.regression.states: the command of tick k holds over [t_k + D·h, t_k + (D+1)·h)).
"""

from __future__ import annotations

from collections import deque

from furuta_rt.sim.simulator import Simulator


class CommandPath:
    """Send a command and advance the simulator one control period, with the rig's command timing."""

    def __init__(self, sim: Simulator, command_delay_ticks: int) -> None:
        if command_delay_ticks < 0:
            raise ValueError(f"command_delay_ticks must be >= 0, got {command_delay_ticks}")
        self.sim = sim
        ticks, _ = sim.model.command_timing(command_delay_ticks)  # the delay line carries the rest
        self._at_sample = ticks == 0
        # commands still on their way to the driver when they act more than one tick after their sample
        self._queue: deque[float] = deque([0.0] * max(ticks - 1, 0))

    def send_and_advance(self, command: float) -> None:
        """``command`` answers the sample just taken; the plant is integrated to the next sample."""
        sim = self.sim
        if self._at_sample:
            sim.set_command(command)
            sim.advance()
            return
        self._queue.append(command)
        sim.advance()
        sim.set_command(self._queue.popleft())
