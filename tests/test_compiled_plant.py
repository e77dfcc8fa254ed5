"""The compiled plant (furuta_rt/sim/csrc/plant.c) against the reference simulator, tick for tick.

Both integrate the same substeps with the same IEEE-754 operations in the same order, so they must agree far below
anything physical: the bound is 1e-12 (rad, rad/s, bristle m) at every 1 kHz tick — nine orders under one count
of the 4096-count encoder — and the DAQ readings (ADC counts with the seeded noise, encoder count) must be
identical at every tick. Stick–slip is a discontinuous map (a substep sticks or slides), so a wrong branch shows at
once as a state jump far above the bound. Every case drives the plant with a command that changes each tick and
reverses, through the friction regimes the case names.
"""

from __future__ import annotations

import dataclasses
import math

import pytest

from furuta_rt.model.coupling import Coupling
from furuta_rt.model.friction import Coulomb, CoulombStiction, JointFriction
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.compiled import CompiledSimulator, make_simulator
from furuta_rt.sim.simulator import Simulator
from hil_mock.config import build_config

SUBSTEP_HZ = 10_000
TICK_SUBSTEPS = 10  # 1 kHz device ticks
BOUND = 1e-12
LUGRE = ["arm_lugre.sigma0=50", "arm_lugre.sigma1=1", "arm_lugre.Fc=0.03", "arm_lugre.Fs=0.04", "arm_lugre.vs=0.1"]
CASES = {
    "nominal": ("thesis", []),
    "stick_slip": ("thesis", ["arm_coulomb.Fc=0.02", "arm_stiction.Fs=0.03", "arm_spring.k=0.01",
                              "arm_bias.tau=0.002", "input_delay.delay=0.0023", "input_deadzone.width=0.004",
                              "pendulum_viscous.bp=1e-5", "theta_offset.offset=0.01"]),
    "lugre": ("thesis", [*LUGRE, "arm_viscous.Fv=0.002", "input_saturation.limit=0.05"]),
    "dc_motor": ("qube_servo2", ["arm_coulomb.Fc=0.001"]),
}


def models(case: str) -> RigModel:
    rig_name, effects = CASES[case]
    cfg = build_config(rig=rig_name, effects=effects)
    return RigModel.from_config(cfg.load_rig(), cfg.effects)


def command(k: int, amplitude: float) -> float:
    """A command that changes every tick and reverses every 0.3 s: sliding, stopping and sticking in turn."""
    return amplitude * math.sin(0.02 * k) * (1.0 if (k // 300) % 2 else -1.0)


def state(sim: Simulator) -> tuple[float, ...]:
    return sim.theta, sim.theta_dot, sim.phi, sim.phi_dot, sim.y, sim.y_dot, sim.z, sim.arm_friction_torque


def run_pair(model: RigModel, ticks: int, amplitude: float, x0: tuple[float, float, float, float]) -> int:
    """Run both plants ``ticks`` 1 kHz ticks; assert agreement at each; return the ticks the arm was stuck."""
    ref = Simulator(model, rate_hz=SUBSTEP_HZ, substep_hz=SUBSTEP_HZ, seed=4, x0=x0)
    fast = CompiledSimulator(model, rate_hz=SUBSTEP_HZ, substep_hz=SUBSTEP_HZ, seed=4, x0=x0)
    stuck = 0
    for k in range(ticks):
        u = command(k, amplitude)
        ref.set_command(u)
        fast.set_command(u)
        ref.advance(TICK_SUBSTEPS)
        fast.advance(TICK_SUBSTEPS)
        diff = max(abs(a - b) for a, b in zip(state(ref), state(fast), strict=True))
        assert diff <= BOUND, f"tick {k}: compiled plant off the reference by {diff:g}"
        assert ref.stuck == fast.stuck, f"tick {k}: stick/slip differs"
        assert ref.sample() == fast.sample(), f"tick {k}: DAQ readings differ"
        assert ref.commands_in_flight == fast.commands_in_flight
        stuck += ref.stuck
    assert ref.t == fast.t
    return stuck


@pytest.mark.parametrize("case", sorted(CASES))
def test_compiled_plant_agrees_with_the_reference_tick_for_tick(case: str) -> None:
    model = models(case)
    amplitude = 0.05 if case != "dc_motor" else 2.0  # N m on the thesis rig, V on the Qube
    stuck = run_pair(model, 2000, amplitude, (0.4, 0.0, 0.0, 0.0))
    if case == "stick_slip":  # the case is there to exercise the stuck branch and the breakaway
        assert 50 < stuck < 1950, f"stick_slip stuck {stuck} of 2000 ticks: the case does not alternate"


def test_friction_step_reaches_the_compiled_plant() -> None:
    """hil_mock's friction_step fault changes the arm's friction mid-run (Simulator.set_arm_friction)."""
    model = models("stick_slip")
    ref = Simulator(model, rate_hz=SUBSTEP_HZ, substep_hz=SUBSTEP_HZ, x0=(0.2, 0.0, 0.0, 0.0))
    fast = CompiledSimulator(model, rate_hz=SUBSTEP_HZ, substep_hz=SUBSTEP_HZ, x0=(0.2, 0.0, 0.0, 0.0))
    worn = JointFriction(dry=CoulombStiction(Fc=0.005, Fs=0.006))
    for k in range(1000):
        if k == 500:
            ref.set_arm_friction(worn)
            fast.set_arm_friction(worn)
        for sim in (ref, fast):
            sim.set_command(command(k, 0.05))
            sim.advance(TICK_SUBSTEPS)
        assert max(abs(a - b) for a, b in zip(state(ref), state(fast), strict=True)) <= BOUND, k
    assert fast.model.arm_friction == worn


def test_delay_line_round_trip() -> None:
    model = models("stick_slip")
    fast = CompiledSimulator(model, rate_hz=SUBSTEP_HZ, substep_hz=SUBSTEP_HZ)
    n = len(fast.commands_in_flight)
    assert n == 23  # 2.3 ms at 10 kHz
    fast.set_commands_in_flight([0.001 * i for i in range(n)])
    assert fast.commands_in_flight == tuple(0.001 * i for i in range(n))
    with pytest.raises(ValueError, match="holds 23"):
        fast.set_commands_in_flight([0.0])


def test_models_plant_c_does_not_cover_run_on_the_reference() -> None:
    """A compliant coupling or a smoothed Coulomb law is not in plant.c: make_simulator falls back, and
    CompiledSimulator refuses rather than integrate a different model."""
    base = models("nominal")
    for model in (dataclasses.replace(base, coupling=Coupling(rotor_inertia=1e-5, stiffness=50.0)),
                  dataclasses.replace(base, arm_friction=JointFriction(dry=Coulomb(Fc=0.01, epsilon=0.01))),
                  dataclasses.replace(base, pendulum_friction=JointFriction(dry=Coulomb(Fc=1e-4)))):
        assert type(make_simulator(model)) is Simulator
        with pytest.raises(ValueError, match="does not cover"):
            CompiledSimulator(model)
    assert type(make_simulator(base)) is CompiledSimulator
    assert type(make_simulator(base, compiled=False)) is Simulator


def test_hil_mock_device_defaults_to_c_firmware_and_compiled_plant_with_the_same_samples() -> None:
    """hil-mock's default device (C firmware core, compiled plant) sends the SAMPLE frames, byte for byte, that the
    Python device with the reference simulator sends for the same COMMANDs: the compiled plant changes the speed,
    not the rig."""
    from firmware_protocol import CommandFlags, Sample, StreamDecoder, encode, encode_command, make_hello
    from hil_mock.c_firmware import CFirmware, make_firmware

    effects = CASES["stick_slip"][1]
    frames: dict[str, list[bytes]] = {}
    for plant, device in (("compiled", {}), ("python", {"firmware": "python", "plant": "python"})):
        cfg = build_config(effects=effects, device={"rate_hz": 1000, **device})  # "compiled": hil-mock's defaults
        rig = cfg.load_rig()
        fw = make_firmware(cfg.device.firmware, rig, RigModel.from_config(rig, cfg.effects), cfg.device, 1000)
        if plant == "compiled":
            assert isinstance(fw, CFirmware) and type(fw.sim) is CompiledSimulator
        else:
            assert not isinstance(fw, CFirmware) and type(fw.sim) is Simulator
        hello = make_hello()
        fw.receive(encode(hello))
        fw.tx.clear()
        dec, out = StreamDecoder(), []
        for k in range(1500):
            fw.tick()
            for frame in fw.tx:
                for m in dec.feed(frame):
                    if type(m) is Sample:
                        out.append(frame)
                        counts = round(3000 * math.sin(0.02 * k))  # ±0.09 of full scale, reversing
                        fw.receive(encode_command(hello.nonce, m.seq, counts, CommandFlags.ENABLE))
            fw.tx.clear()
        frames[plant] = out
    assert len(frames["compiled"]) == 1500
    phi = [m.phi_count for f in frames["compiled"] for m in StreamDecoder().feed(f)]
    assert max(phi) - min(phi) > 20  # the arm moved under the reversing torque (71 counts): not a resting rig
    assert frames["compiled"] == frames["python"]


@pytest.mark.parametrize("case", ["stick_slip", "lugre", "dc_motor"])
def test_c_device_tick_agrees_with_the_python_device_tick_for_tick(case: str) -> None:
    """The device tick in C (hil_mock/csrc/device.c: sensor path, firmware core, frames out, plant substeps in one call)
    against the reference device (Python firmware, Python simulator, Calibration.to_counts): every frame identical and
    the plant states within the bound at every tick, across the noise blocks' hand-overs (2 draws a tick, 4096 a
    block: one before and one after the restart), a STOP and a new session (the rig put back, the noise restarted
    from its seed), an overrun's skipped periods and a COMMAND at negative full scale. Cases: the thesis rig (θ
    wraps, Bessel path, θ and θ̇ noise, transport delay, stick–slip), LuGre with saturation, a DC motor rig (saturating
    ADC, no Bessel path, θ̇ noise)."""
    from firmware_protocol import (
        CommandFlags,
        HelloAck,
        Sample,
        Stop,
        StreamDecoder,
        encode,
        encode_command,
        make_hello,
    )
    from hil_mock.c_firmware import CFirmware, make_firmware

    def protocol(frames: list[bytes]) -> list[bytes]:
        """The frames, each HELLO_ACK (which names the firmware and its version) left out."""
        return [f for f in frames if not any(type(m) is HelloAck for m in StreamDecoder().feed(f))]

    rig_name, effects = CASES[case]
    devices = []
    for device in ({}, {"firmware": "python", "plant": "python"}):
        cfg = build_config(rig=rig_name, effects=effects, device={"rate_hz": 1000, **device})
        rig = cfg.load_rig()
        devices.append(make_firmware(cfg.device.firmware, rig, RigModel.from_config(rig, cfg.effects), cfg.device,
                                     1000))
    fast, ref = devices
    assert isinstance(fast, CFirmware) and fast.fused and not isinstance(ref, CFirmware)
    hellos = [make_hello(), make_hello()]
    decoders = [StreamDecoder(), StreamDecoder()]
    session, samples, stuck_or_slow = 0, 0, 0
    for fw in devices:
        fw.receive(encode(hellos[0]))
    for k in range(4600):
        if k == 2300:  # the host stops, then a new session on the idle device: the rig put back at its start
            session = 1
            for fw in devices:
                fw.receive(encode(Stop(0)) + encode(hellos[1]))
        if k == 3500:
            for fw in devices:
                fw.skip(3)
        for fw in devices:
            fw.tick()
        assert protocol(fast.tx) == protocol(ref.tx), f"tick {k}"
        assert max(abs(a - b) for a, b in zip(state(fast.sim), state(ref.sim), strict=True)) <= BOUND, f"tick {k}"
        assert fast.output == ref.output and fast.plant_time == ref.plant_time
        for frame in fast.tx:
            for m in decoders[0].feed(frame):
                if type(m) is Sample:
                    samples += 1
                    counts = -32768 if k % 500 == 7 else round(9000 * math.sin(0.013 * k))
                    for fw in devices:
                        fw.receive(encode_command(hellos[session].nonce, m.seq, counts, CommandFlags.ENABLE))
        stuck_or_slow += fast.sim.phi_dot == 0.0 or abs(fast.sim.phi_dot) < 0.05
        for fw in devices:
            fw.tx.clear()
    assert samples == 4600
    assert fast.replacements == ref.replacements == 1
    assert fast.commands_applied == ref.commands_applied > 4500
    assert 0 < stuck_or_slow < 4600  # the arm moved and came to (near) rest: the friction branches both ran


def test_one_reading_quantises_as_an_array_does() -> None:
    """count_of's single-reading path (the DAQ's tick, without numpy) gives the array path's counts, ties included."""
    import numpy as np

    from furuta_rt.model.sensors import count_of

    step = 2 * math.pi / 4096
    x = np.concatenate([np.linspace(-7.0, 7.0, 4001), (np.arange(-50, 50) + 0.5) * step, [0.0, -0.0, 1e-300]])
    for phase in (0.0, 0.25, -0.3):
        assert [count_of(float(v), step, phase) for v in x] == count_of(x, step, phase).tolist()


def test_closed_loop_runs_the_compiled_plant_with_the_reference_recording() -> None:
    """run_closed_loop (and so the suites' recordings) and diagnose's simulations start ``fast_simulator``: the
    compiled plant where it covers the model, with the Python simulator's recording count for count (the true
    states within the bound); a model plant.c does not cover runs on the reference."""
    import numpy as np

    from furuta_rt.config import load_rig
    from furuta_rt.model.effects import effects_from_assignments
    from furuta_rt.sim.closed_loop import run_closed_loop
    from furuta_rt.sim.compiled import fast_simulator

    rig = load_rig("thesis")
    effects = effects_from_assignments(CASES["stick_slip"][1])
    reference = run_closed_loop(rig, 2.0, effects=effects, seed=3, simulator=Simulator)
    fast = run_closed_loop(rig, 2.0, effects=effects, seed=3)
    for name in ("theta", "theta_dot", "phi", "u"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(reference, name))
    for name in ("true_theta", "true_theta_dot", "true_phi", "true_phi_dot", "friction"):
        assert np.max(np.abs(fast.extra[name] - reference.extra[name])) <= BOUND
    assert np.ptp(reference.extra["friction"]) > 0.04  # the arm stuck and slid: both branches of plant.c ran
    model = RigModel.from_config(rig, effects)
    assert type(fast_simulator(model)) is CompiledSimulator
    coupled = dataclasses.replace(model, coupling=Coupling(rotor_inertia=1e-5, stiffness=50.0, damping=0.02))
    assert type(fast_simulator(coupled)) is Simulator
