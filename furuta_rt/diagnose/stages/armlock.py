"""An arm that stays put: dry friction or an actuator dead band, from what the rests can show.

Where the arm's encoder holds one count, eq. 4's arm row with φ̇ = φ̈ = 0 gives the torque that held it there: the
pendulum's reaction (FurutaPlant.inverse_dynamics at the arm's rest) less the actuator's torque for the command.
Without dry friction that torque would have turned the arm — by the rest's double integral through the arm's
inertia and configured damping. When that turn is many encoder counts and the count did not move, something held
the arm with at least that torque.

At zero command (|u| under 1 % of the actuator's limit) a dead band exerts nothing either way, so a rest against
the pendulum's reaction is dry friction (stiction or Coulomb: eq. 1–2 hold up to their stick limit) — or a lock on
the arm, which no recording tells from a large stiction. With a small command the two look alike: friction up to
|K·u| or a dead band as wide as |u| both keep the arm still. They come apart where the dead band cannot act: a rest
at zero command with the pendulum swinging (the arm must resist the reaction), or a slow ramp of u in both
directions (a dead band shifts the start by one |u| at any load; friction by one torque, whatever the command gain).

Rests need no derivative of φ and few samples: this stage assesses the arm where the regression has too few rows
(a short recording at 50 Hz).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.judgement import noise_model
from furuta_rt.diagnose.regression.states import GaussianFilter, Prepared
from furuta_rt.model.rig import RigModel

COMMAND_OFF = 0.01  # |u| under this share of the actuator's limit is zero command
MIN_REST_S = 0.1  # a rest: the arm at one encoder count at least this long ...
MIN_REST_SAMPLES = 4  # ... over at least this many samples
REST_COUNTS = 10.0  # the free arm would have turned this many counts over the rest: it was held
SIGMA = 0.04  # s: the pendulum's states for the reaction torque (the diagnosis's pendulum kernel width)
HELD_Z = 5.0  # the held torque counts above this many times the noise of its estimate
TRIM_SIGMAS = 2.0  # a rest's ends trimmed by this many kernel widths: the smoothed θ̈ there sees the motion around it


@dataclass(frozen=True)
class Rest:
    start: float  # s
    stop: float
    command: float  # largest |u| acting during the rest (command units)
    held: float  # the torque that held the arm (90th percentile of its magnitude), N m
    turn: float  # how far the free arm would have turned, rad

    @property
    def zero_command(self) -> bool:
        return self.command == 0.0

    def as_json(self) -> dict:
        return {"t": [self.start, self.stop], "command": self.command, "held_torque": self.held, "free_turn_rad": self.turn}


@dataclass(frozen=True)
class ArmLock:
    rests: list[Rest]  # every rest that held the arm against a torque (turn ≥ REST_COUNTS counts)
    at_zero: float  # the largest torque held at zero command (0 when no such rest), N m
    at_small: float  # ... with a small command, N m
    small_command: float  # the largest |u| among the small-command rests
    known_limit: float  # the config's own dry-friction stick limit, N m
    verdict: str  # "dry friction" | "look-alike" | "known"
    rests_seen: int  # all rests of the arm, held against a torque or not

    def as_json(self) -> dict:
        return {"verdict": self.verdict, "held_at_zero_command": self.at_zero, "held_at_small_command": self.at_small,
                "small_command": self.small_command, "config_stick_limit": self.known_limit, "rests": self.rests_seen,
                "held_rests": [r.as_json() for r in self.rests]}

    def text(self) -> str:
        zero = [r for r in self.rests if r.zero_command]
        if self.verdict == "known":
            return (f"the arm rests {len(self.rests)} times against up to {max(self.at_zero, self.at_small):.3g} N m, "
                    f"within the config's stick limit {self.known_limit:.3g} N m")
        if self.verdict == "dry friction":
            r = max(zero, key=lambda r: r.held)
            return (f"the arm stays at one encoder count at zero command {len(zero)} time(s) while the pendulum pulls it "
                    f"(up to {self.at_zero:.3g} N m, t = {r.start:.2f}–{r.stop:.2f} s; free, it would have turned "
                    f"{r.turn:.3g} rad): dry friction holding ≥ {self.at_zero:.3g} N m (stiction or Coulomb, eq. 1–2) — "
                    f"a dead band on u exerts nothing at zero command and cannot; a mechanical lock of the arm looks the same")
        return (f"the arm stays still under small commands (|u| ≤ {self.small_command:.3g}) that would have turned it, up "
                f"to {self.at_small:.3g} N m: dry friction of that size or a dead band as wide as |u| look alike here; "
                "a rest at zero command with the pendulum swinging (friction holds the arm against its pull, a dead band "
                "does not) or a slow ramp of u in both directions separates them")


def rests(prep: Prepared) -> list[tuple[int, int]]:
    """[start, stop) of every stretch of ≥ MIN_REST_S and ≥ MIN_REST_SAMPLES at one arm encoder count."""
    cnt = np.round(prep.phi / prep.phi_lsb).astype(np.int64)
    change = np.flatnonzero(np.diff(cnt) != 0) + 1
    edges = np.concatenate([[0], change, [prep.n]])
    need = max(MIN_REST_SAMPLES, int(np.ceil(MIN_REST_S / prep.dt)))
    return [(int(a), int(b)) for a, b in itertools.pairwise(edges) if b - a >= need]


def assess(prep: Prepared, rig: RigConfig) -> ArmLock | None:
    """The rests that held the arm against a torque, and what they say; None when there are none."""
    spans = rests(prep)
    if not spans:
        return None
    model = RigModel.from_config(rig)
    plant, act = model.plant, model.actuator
    s = prep.states(SIGMA)
    th, thd, thdd = s.theta, s.theta_dot, s.theta_ddot
    zero = np.zeros_like(th)
    reaction = plant.inverse_dynamics(th, thd, zero, thdd, zero)[1]  # the arm torque that keeps φ̈ = 0
    inertia = plant.inverse_dynamics(th, zero, zero, zero, zero + 1.0)[1] - plant.inverse_dynamics(th, zero, zero, zero, zero)[1]
    damping = act.torque_terms(0.0)[1] + (model.arm_friction.viscous.Fv if model.arm_friction.viscous else 0.0)
    dry = model.arm_friction.dry
    known = float(dry.stick_limit) if dry is not None else 0.0
    limit = COMMAND_OFF * rig.actuator.limit
    lag = int(np.ceil(prep.command_lag / prep.dt - 1e-9))  # the command acting at sample k is u[k − lag]
    acting = np.concatenate([np.zeros(lag), prep.u[: prep.n - lag]]) if lag else prep.u
    torque0 = np.array([act.torque_terms(float(u))[0] for u in acting])
    held: list[Rest] = []
    floor = HELD_Z * torque_noise(prep, rig, plant.p.gamma)
    edge = int(np.ceil(4 * SIGMA / prep.dt))  # the states' kernel reaches past the recording's ends there
    trim = int(np.ceil(TRIM_SIGMAS * SIGMA / prep.dt))  # ... and past a rest's ends into the motion around it
    off = np.abs(acting) <= limit
    for a, b in spans:
        a0, b0 = max(a + trim, edge), min(b - trim, prep.n - edge)
        # a rest through a change of command (zero ↔ not): each part read on its own (no trim inside: the arm is still)
        cuts = [a0, *(a0 + 1 + np.flatnonzero(off[a0 : b0 - 1] != off[a0 + 1 : b0])), b0]
        for c0, c1 in itertools.pairwise(cuts):
            if c1 - c0 < MIN_REST_SAMPLES:
                continue
            command = 0.0 if off[c0] else float(np.max(np.abs(acting[c0:c1])))
            # friction = what held it: reaction needed − actuator torque (zero command: the reaction alone)
            friction = reaction[c0:c1] - (0.0 if command == 0.0 else torque0[c0:c1])
            turn = _free_turn(-friction, inertia[c0:c1], damping, prep.dt)
            level = float(np.percentile(np.abs(friction), 90))
            if turn >= REST_COUNTS * prep.phi_lsb and level >= floor:
                held.append(Rest(float(prep.t[c0]), float(prep.t[c1 - 1]), command, level, turn))
    if not held:
        return None
    at_zero = max((r.held for r in held if r.zero_command), default=0.0)
    small = [r for r in held if not r.zero_command]
    at_small = max((r.held for r in small), default=0.0)
    small_command = max((r.command for r in small), default=0.0)
    verdict = "known" if max(at_zero, at_small) <= known else "dry friction" if at_zero > known else "look-alike"
    return ArmLock(held, at_zero, at_small, small_command, known, verdict, len(spans))


def torque_noise(prep: Prepared, rig: RigConfig, gamma: float) -> float:
    """The noise of the pendulum's reaction on the arm, γ·δθ̈: the recording's θ noise (measured, at least the θ
    quantisation's) through the kernel's second derivative."""
    lsb = rig.sensors.theta_rad_per_count if rig.sensors.bessel_cutoff is None else 0.0
    theta = max(noise_model.estimate(prep, rig).rms(prep.dt, prep.bessel), lsb / np.sqrt(12.0))
    return abs(gamma) * theta * float(np.linalg.norm(GaussianFilter.build(SIGMA, prep.dt).kernels[2]))


def _free_turn(torque: np.ndarray, inertia: np.ndarray, damping: float, dt: float) -> float:
    """How far an arm free of dry friction turns from rest under ``torque`` (its inertia and viscous damping as
    given), semi-implicit Euler at the recording's step: the largest |φ| reached."""
    phi = rate = 0.0
    out = 0.0
    for tau, j in zip(torque, inertia, strict=True):
        rate = (rate + dt * tau / j) / (1.0 + dt * damping / j)
        phi += dt * rate
        out = max(out, abs(phi))
    return out


DRY = ("arm_coulomb", "arm_stiction", "arm_lugre")


def declare(lock: ArmLock | None, found: list[str], known: list[str], experiment: str) -> list[dict]:
    """Look-alike entries for a dead band the diagnosis names (``found``: its effect names; ``known``: the rig's own)
    while the rests show dry friction it has not named, or cannot tell the two apart: one entry, or none."""
    if "input_deadzone" not in found or any(n in found or n in known for n in DRY) or lock is None:
        return []
    if lock.verdict == "dry friction":
        reason = (f"input_deadzone is named, but {lock.text()}: the arm's dry friction is present, and the dead band may be "
                  "that friction")
    elif lock.verdict == "look-alike":
        reason = f"input_deadzone is named, but {lock.text()}"
    else:
        return []
    return [{"effects": ["input_deadzone", "arm_stiction"], "reported": "input_deadzone", "reason": reason,
             "alternative": {"name": "arm_stiction", "params": {"Fs": max(lock.at_zero, lock.at_small)}},
             "experiment": experiment, "rests": lock.as_json()}]


BREAKAWAY_MARGIN = 1.3  # the rests hold this many times the sliding level found: a breakaway above it


def above_sliding(lock: ArmLock | None, found: dict[str, dict[str, float]]) -> list[str]:
    """A note when the rests at zero command hold clearly more (BREAKAWAY_MARGIN ×) than the sliding Coulomb level
    the diagnosis found and no breakaway torque was found: the friction's stick limit is above its sliding level
    (stiction, eq. 2)."""
    fc = found.get("arm_coulomb", {}).get("Fc")
    if lock is None or fc is None or "arm_stiction" in found or "arm_lugre" in found:
        return []
    if lock.at_zero > BREAKAWAY_MARGIN * fc:
        return [f"the arm's rests at zero command hold {lock.at_zero:.3g} N m, {lock.at_zero / fc:.1f} × the sliding "
                f"Coulomb level found (Fc = {fc:.3g} N m): its breakaway torque is above the sliding level (stiction, "
                "eq. 2), at least by that much"]
    return []


def summary_clause(lock: ArmLock | None, arm_assessed: bool) -> str:
    """What the rests add to the one-line summary when the arm equation could not be assessed (a short or slow file:
    the rests are then the arm's whole story); '' otherwise."""
    if lock is None or arm_assessed or lock.verdict == "known":
        return ""
    if lock.verdict == "dry friction":
        return f"; the arm's rests at zero command: dry friction holding ≥ {lock.at_zero:.3g} N m"
    return f"; the arm's rests under small commands: dry friction (≤ {lock.at_small:.3g} N m) or a dead band, alike here"
