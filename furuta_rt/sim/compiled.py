"""The core simulator's plant integrated in C (furuta_rt/sim/csrc/plant.c): the same trajectory, several times sooner.

``CompiledSimulator`` is furuta_rt.sim.simulator.Simulator with ``advance`` run by plant.c — eq. 4, the arm's
viscous, set-valued dry (stick/slip) or LuGre friction, the pendulum's viscous friction, the spring, the arm bias,
the Bessel filter and the actuator's transport delay — substep for substep in the reference's order of operations.
Everything else stays the reference's: the actuator's shaping (``Actuator.torque_terms``, once per command), the
sensors (``sample``/``measure``: noise, ADC, encoder), the state attributes a caller writes (a fault's push, a
teacher-forced pendulum), the friction step. The Python simulator remains the one definition;
tests/test_compiled_plant.py holds the two together tick for tick. Why C and not numpy: the work is a 10 kHz scalar
recurrence (each substep needs the last), which numpy cannot vectorise, and C builds with the compiler and cache
the firmware core already uses (firmware_protocol.hostbuild).

A model with an effect plant.c does not cover (compliant coupling, smooth-Coulomb or pendulum dry friction, a
torque-law effect) runs on the Python simulator: ``make_simulator`` decides; ``fast_simulator`` also falls back
where no C compiler is installed (hil_mock's device needs one anyway; a simulation or a diagnosis does not).
"""

from __future__ import annotations

import ctypes
import functools
from pathlib import Path

from firmware_protocol.hostbuild import BuildError, host_library
from furuta_rt.model.friction import JointFriction
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.simulator import Simulator

SOURCE = Path(__file__).parent / "csrc" / "plant.c"
HEADER = SOURCE.with_suffix(".h")
STATE = ("theta", "theta_dot", "phi", "phi_dot", "y", "y_dot", "z", "arm_friction_torque")  # then stuck (plant.c)


class PlantParams(ctypes.Structure):
    """plant.c ``plant_params_t``."""

    _fields_ = (
        *((name, ctypes.c_double) for name in (
            "alpha", "beta", "gamma", "eps", "fv_arm", "bp", "k", "phi0", "fa0", "fa1", "offset", "bias", "fc",
            "fs", "sigma0", "sigma1", "l_fc", "l_fs", "vs", "l_fv", "h")),
        ("set_valued", ctypes.c_int),
        ("lugre", ctypes.c_int),
    )


@functools.cache
def load_library() -> ctypes.CDLL:
    """plant.c built for this machine (cached like the firmware core's host build)."""
    lib = ctypes.CDLL(str(host_library(sources=(SOURCE,), headers=(HEADER,), name="libfuruta_plant", libs=("-lm",),
                                         include_dirs=(SOURCE.parent,))))
    lib.plant_params_size.restype = ctypes.c_uint
    if lib.plant_params_size() != ctypes.sizeof(PlantParams):
        raise RuntimeError("furuta_rt/sim/csrc/plant.c: plant_params_t and compiled.PlantParams differ in size")
    dp = ctypes.POINTER(ctypes.c_double)
    lib.plant_advance.argtypes = (ctypes.POINTER(PlantParams), dp, dp, ctypes.c_int, ctypes.POINTER(ctypes.c_int),
                                  ctypes.c_double, ctypes.c_double, ctypes.c_double, ctypes.c_long)
    lib.plant_advance.restype = None
    return lib


def unsupported(model: RigModel) -> str | None:
    """Why plant.c cannot run ``model`` (None: it can)."""
    if model.coupling is not None:
        return "a compliant coupling"
    if model.joint_torques:
        return "the torque laws of " + ", ".join(e.name for e in model.joint_torques)
    if model.pendulum_friction.dry is not None or model.pendulum_friction.lugre is not None:
        return "dry friction at the pendulum"
    dry = model.arm_friction.dry
    if dry is not None and getattr(dry, "epsilon", 0.0) > 0:
        return "a smoothed Coulomb arm friction"
    return None


def _state_field(i: int, name: str) -> property:
    """A state attribute of the Simulator kept in plant.c's state array (read and written in place)."""

    def get(self: CompiledSimulator) -> float:
        return self._state[i]

    def put(self: CompiledSimulator, value: float) -> None:
        self._state[i] = value

    return property(get, put, doc=f"{name}, in plant.c's state array")


class CompiledSimulator(Simulator):
    """Simulator whose ``advance`` runs in plant.c (see the module docstring); same constructor. The plant's state
    lives in plant.c's array: the attributes of the reference (theta, …, stuck) read and write it, so a tick hands
    C nothing to copy."""

    for _i, _name in enumerate(STATE):
        locals()[_name] = _state_field(_i, _name)
    del _i, _name

    @property
    def stuck(self) -> bool:
        return self._state[len(STATE)] != 0.0

    @stuck.setter
    def stuck(self, value: bool) -> None:
        self._state[len(STATE)] = 1.0 if value else 0.0

    def __init__(self, model: RigModel, *args: object, **kwargs: object) -> None:
        why = unsupported(model)
        if why is not None:
            raise ValueError(f"the compiled plant does not cover {why}: use Simulator")
        self._state = (ctypes.c_double * (len(STATE) + 1))()
        super().__init__(model, *args, **kwargs)  # type: ignore[arg-type]
        self._lib = load_library()
        n = len(self._delay_line)
        self._n_delay = n
        self._ring = (ctypes.c_double * max(3 * n, 1))()
        self._head = ctypes.c_int(0)
        self.set_commands_in_flight(tuple(self._delay_line))
        self._params = PlantParams()
        self._load_params()
        self._call = self._lib.plant_advance
        self._refs = (ctypes.byref(self._params), self._state, self._ring, n, ctypes.byref(self._head))

    def _load_params(self) -> None:
        m = self.model
        p = m.plant.p
        q = self._params
        q.alpha, q.beta, q.gamma, q.eps = p.alpha, p.beta, p.gamma, p.epsilon
        q.fv_arm, q.bp, q.k, q.phi0 = self._fv_arm, self._bp, self._k, self._phi0
        q.fa0, q.fa1, q.offset, q.bias = self._fa0, self._fa1, m.theta_offset, self._bias
        q.fc, q.fs, q.set_valued = self._fc, self._fs, int(self._set_valued)
        lugre = self._lugre
        q.lugre = int(lugre is not None)
        if lugre is not None:
            q.sigma0, q.sigma1, q.l_fc, q.l_fs, q.vs, q.l_fv = (
                lugre.sigma0, lugre.sigma1, lugre.Fc, lugre.Fs, lugre.vs, lugre.Fv)
        q.h = self.h

    def set_arm_friction(self, friction: JointFriction) -> None:
        super().set_arm_friction(friction)
        why = unsupported(self.model)
        if why is not None:
            raise ValueError(f"the compiled plant does not cover {why}")
        self._load_params()

    @property
    def commands_in_flight(self) -> tuple[float, ...]:
        n, head, ring = self._n_delay, self._head.value, self._ring
        return tuple(ring[3 * ((head + i) % n) + 2] for i in range(n))

    def set_commands_in_flight(self, commands: list[float] | tuple[float, ...]) -> None:
        if len(commands) != self._n_delay:
            raise ValueError(f"the delay line holds {self._n_delay} substep commands, got {len(commands)}")
        self._head.value = 0
        terms = self.model.actuator.torque_terms
        for i, c in enumerate(commands):
            self._ring[3 * i:3 * i + 3] = (*terms(float(c)), float(c))

    def advance(self, ticks: int = 1) -> None:
        """Integrate ``ticks`` control periods with the current command, in plant.c."""
        if self.command != self._shaped_for:
            self._shaped_for = self.command
            self._shaped = self.model.actuator.torque_terms(self.command)
        tau0, damp = self._shaped
        self._call(*self._refs, tau0, damp, self.command, ticks * self.n_sub)
        self.t += ticks / self.rate_hz


def make_simulator(model: RigModel, *args: object, compiled: bool = True, **kwargs: object) -> Simulator:
    """The plant for ``model``: compiled when asked and plant.c covers the model, else the Python reference."""
    if compiled and unsupported(model) is None:
        return CompiledSimulator(model, *args, **kwargs)
    return Simulator(model, *args, **kwargs)  # type: ignore[arg-type]


@functools.cache
def _plant_builds() -> bool:
    try:
        load_library()
    except BuildError:
        return False
    return True


def fast_simulator(model: RigModel, *args: object, **kwargs: object) -> Simulator:
    """A Simulator for ``model`` (Simulator's constructor arguments): compiled where plant.c covers the model and
    builds on this machine, else the Python reference."""
    return make_simulator(model, *args, compiled=_plant_builds(), **kwargs)
