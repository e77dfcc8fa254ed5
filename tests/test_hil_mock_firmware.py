"""hil_mock without a pty: the firmware's protocol rules (PROTOCOL.md §4–7), config, effects, faults."""

from __future__ import annotations

import itertools
import math

import pytest

from firmware_protocol import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    CommandFlags,
    Config,
    Hello,
    HelloAck,
    Sample,
    Status,
    StatusFlags,
    Stop,
    StreamDecoder,
    actuator_to_counts,
    encode,
    encode_command,
)
from furuta_rt.errors import UserError
from furuta_rt.model.friction import Coulomb
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.closed_loop import run_closed_loop
from hil_mock.cli import main
from hil_mock.config import build_config, load_mock_config
from hil_mock.faults import FaultEvent, LinkFaults, parse_fault
from hil_mock.firmware import Firmware

ENABLE = int(CommandFlags.ENABLE)
CLEAR = int(CommandFlags.CLEAR_FAULT)


class Bench:
    """A Firmware with a host-side decoder: feed host frames, tick, collect device messages."""

    def __init__(self, rate: int = 500, **device: object) -> None:
        cfg = build_config(device={"rate_hz": rate, **device})
        rig = cfg.load_rig()
        self.fw = Firmware(rig, RigModel.from_config(rig, cfg.effects), cfg.device, rate)
        self.dec = StreamDecoder()

    def send(self, frame: bytes) -> None:
        self.fw.receive(frame)

    def tick(self, n: int = 1) -> list:
        out = []
        for _ in range(n):
            self.fw.tick()
            out += self.dec.feed(b"".join(self.fw.tx))
            self.fw.tx.clear()
        return out

    def hello(self, **kw: int) -> HelloAck:
        self.send(encode(Hello(kw.get("version", PROTOCOL_VERSION), kw.get("hash", SCHEMA_HASH), 77)))
        msgs = self.tick()
        assert type(msgs[0]) is HelloAck
        return msgs[0]

    def step(self, seq: int, counts: int, flags: int = ENABLE) -> Sample:
        """Answer SAMPLE ``seq``, then tick once; return the next SAMPLE."""
        self.send(encode_command(77, seq, counts, flags))
        return samples(self.tick())[0]


def samples(msgs: list) -> list[Sample]:
    return [m for m in msgs if type(m) is Sample]


def test_hello_ack_reports_the_rig_and_streaming_starts_at_seq_0():
    b = Bench(rate=500)
    assert b.tick(5) == []  # nothing before the handshake
    ack = b.hello()
    assert (ack.protocol_version, ack.schema_hash, ack.nonce) == (PROTOCOL_VERSION, SCHEMA_HASH, 77)
    assert ack.sample_rate_hz == 500 and ack.watchdog_ms == 20
    assert ack.actuator_full_scale == 2.0 and ack.phi_counts_per_rev == 4096
    assert math.isclose(ack.theta_rad_per_count, 2 * math.pi / 65536, rel_tol=1e-7)
    got = samples(b.tick(3))
    assert [s.seq for s in got] == [1, 2, 3]  # seq 0 went out with the HELLO_ACK's tick
    assert [s.t_us for s in got] == [12_000, 14_000, 16_000]  # device clock: 2 ms per tick since boot (tick 5 = seq 0)


@pytest.mark.parametrize(("rig", "kind"), [("thesis", 0), ("qube_servo2", 1), ("macstepien", None)])
def test_every_shipped_rig_serves(rig, kind):
    cfg = build_config(rig=rig)
    r = cfg.load_rig()
    fw = Firmware(r, RigModel.from_config(r, cfg.effects), cfg.device, cfg.rate_hz(r))
    fw.receive(encode(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 1)))
    fw.tick()
    ack, sample = StreamDecoder().feed(b"".join(fw.tx))
    assert type(ack) is HelloAck and type(sample) is Sample
    assert ack.actuator_full_scale == pytest.approx(r.actuator.limit, rel=1e-7)
    assert ack.actuator_kind == (kind if kind is not None else int(r.actuator.kind != "torque"))
    assert ack.phi_counts_per_rev == r.sensors.encoder_counts_per_rev and ack.sample_rate_hz == r.control.rate_hz


def test_wrong_schema_hash_is_refused_with_the_devices_own_identity():
    b = Bench()
    b.send(encode(Hello(PROTOCOL_VERSION, SCHEMA_HASH ^ 1, 5)))
    msgs = b.tick(10)
    assert len(msgs) == 1 and type(msgs[0]) is HelloAck and msgs[0].schema_hash == SCHEMA_HASH
    assert not b.fw.streaming and b.fw.handshakes_refused == 1


def test_command_applied_at_next_tick_and_scaled_by_full_scale():
    b = Bench()
    b.hello()
    out = b.step(0, 16384)  # answers SAMPLE 0 → applied at tick 1
    assert out.seq == 1 and out.status & StatusFlags.ENABLED
    assert b.fw.output == pytest.approx(2.0 * 16384 / 32767)
    b.send(encode_command(77, 1, -32768, ENABLE))  # §4: −32768 acts as −32767
    b.tick()
    assert b.fw.output == -2.0


def test_stale_and_future_commands_are_discarded():
    b = Bench()
    b.hello()
    b.tick(3)  # SAMPLEs 0..3 sent
    b.send(encode_command(77, 10, 1000, ENABLE))  # newer than the last SAMPLE sent
    b.send(encode_command(77, 3, 1000, ENABLE))
    b.send(encode_command(77, 2, 5000, ENABLE))  # older than the accepted one
    s = samples(b.tick())[0]
    assert b.fw.commands_discarded == 2 and b.fw.output == pytest.approx(2.0 * 1000 / 32767)
    assert not s.status & StatusFlags.COMMAND_LATE  # 3 answered SAMPLE 3
    s = samples(b.tick())[0]
    assert s.status & StatusFlags.COMMAND_LATE and b.fw.output > 0  # nothing new: held, flagged late


def test_watchdog_trips_after_watchdog_ms_and_clear_fault_rule():
    b = Bench(rate=1000)
    b.hello()
    seq = 0
    for seq in range(5):
        b.step(seq, 3000)
    assert b.fw.output > 0
    got = []
    for _ in range(25):
        got += b.tick()
    tripped = [s.seq for s in samples(got) if s.status & StatusFlags.WATCHDOG_TRIPPED]
    # last COMMAND applied at tick 5; 20 ms later (tick 25) the watchdog trips
    assert tripped and tripped[0] == 25
    assert any(type(m) is Status and m.flags & StatusFlags.WATCHDOG_TRIPPED for m in got)
    assert b.fw.output == 0.0 and b.fw.watchdog_trips == 1
    last = samples(got)[-1].seq
    s = b.step(last, 3000, ENABLE)  # no CLEAR_FAULT: the fault stays, output zero
    assert s.status & StatusFlags.WATCHDOG_TRIPPED and b.fw.output == 0.0
    s = b.step(s.seq, 3000, ENABLE | CLEAR)  # clears, but zero on the tick that applies it
    assert not s.status & StatusFlags.WATCHDOG_TRIPPED and not s.status & StatusFlags.ENABLED
    assert b.fw.output == 0.0
    assert not samples(b.tick())[0].status & StatusFlags.ENABLED  # ENABLE only from the next COMMAND
    s = b.step(s.seq + 1, 3000, ENABLE)
    assert s.status & StatusFlags.ENABLED and b.fw.output > 0


def test_watchdog_armed_by_handshake():
    b = Bench(rate=1000)
    b.hello()
    got = samples(b.tick(30))
    assert got[19].seq == 20 and got[19].status & StatusFlags.WATCHDOG_TRIPPED
    assert not got[18].status & StatusFlags.WATCHDOG_TRIPPED


def test_config_applies_rate_and_watchdog_or_rejects():
    b = Bench(rate=500)
    b.hello()
    b.step(0, 3000)
    b.send(encode(Config(1000, 50)))
    msgs = b.tick(2)
    st = next(m for m in msgs if type(m) is Status)
    assert (st.rate_hz, st.watchdog_ms) == (1000, 50) and not st.flags & StatusFlags.CONFIG_REJECTED
    assert b.fw.output == 0.0  # applying a CONFIG zeroes the output; ENABLE needed again
    s1, s2 = samples(msgs)
    assert s2.t_us - s1.t_us == 1000 and s2.seq == s1.seq + 1  # new period, seq continues
    b.send(encode(Config(0, 50)))
    st = next(m for m in b.tick() if type(m) is Status)
    assert st.flags & StatusFlags.CONFIG_REJECTED and st.rate_hz == 1000


def test_stop_returns_to_idle_and_hello_restarts_seq():
    b = Bench()
    b.hello()
    b.step(0, 3000)
    b.send(encode(Stop(0)))
    assert samples(b.tick(5)) == [] and b.fw.output == 0.0
    b.hello()
    assert samples(b.tick())[0].seq == 1


def test_status_at_least_once_per_second():
    b = Bench(rate=200, initial_theta=0.0)  # upright equilibrium: no fault in 2 s
    b.hello()
    msgs = []
    for k in range(450):  # 2.25 s, answered
        b.send(encode_command(77, k, 0, ENABLE))
        msgs += b.tick()
    statuses = [m for m in msgs if type(m) is Status]
    assert [s.last_cmd_seq for s in statuses] == [199, 399]  # at 1 s and 2 s after the HELLO
    assert all(s.frames_rx == s.last_cmd_seq + 1 and s.flags == StatusFlags.ENABLED for s in statuses)


def test_overrange_latches_adc_fault_when_the_pendulum_falls():
    """A ±π θ sensor (sensors.theta_wraps = false) saturates at its rail."""
    b = Bench(rate=500, initial_theta=0.3)
    rig = b.fw.rig.model_copy(update={"sensors": b.fw.rig.sensors.model_copy(update={"theta_wraps": False})})
    b.fw = Firmware(rig, RigModel.from_config(rig), b.fw.settings, 500)
    b.hello()
    got = []
    for _ in range(1000):
        got += b.tick()
        if any(s.status & StatusFlags.ADC_OVERRANGE for s in samples(got)):
            break
    first = next(s for s in samples(got) if s.status & StatusFlags.ADC_OVERRANGE)
    assert first.theta_adc == 32767  # θ reached π: the ADC rail


def test_full_turn_theta_sensor_wraps_through_pi_without_overrange():
    """The thesis rig's θ sensor reads the full turn (sensors.theta_wraps): the fallen pendulum swings through π with
    θ's counts wrapping from +32767 to −32768, no ADC_OVERRANGE."""
    b = Bench(rate=500, initial_theta=0.3)
    b.hello()
    got = []
    for _ in range(1000):
        got += b.tick()
    s = samples(got)
    assert not any(x.status & StatusFlags.ADC_OVERRANGE for x in s)
    counts = [x.theta_adc for x in s]
    jumps = [b - a for a, b in itertools.pairwise(counts) if abs(b - a) > 30000]
    assert jumps and all(abs(abs(j) - 65536) < 2000 for j in jumps)  # wraps by one turn, not a glitch


def test_firmware_reproduces_closed_loop_simulation():
    """Same order of operations and seed as run_closed_loop: identical counts at the first ticks and
    trajectories equal up to the COMMAND quantisation over 1 s of balancing with Coulomb friction."""
    from furuta_rt.controller.controller import Controller, Measurement

    cfg = build_config(effects=["arm_coulomb.Fc=0.05"], device={"rate_hz": 500, "seed": 3, "initial_theta": 0.05})
    rig = cfg.load_rig()
    model = RigModel.from_config(rig, cfg.effects)
    fw = Firmware(rig, model, cfg.device, 500)
    rec = run_closed_loop(rig, 1.0, effects=cfg.effects, seed=3, x0=(0.05, 0.0, 0.0, 0.0))
    ctrl = Controller.from_rig(rig)
    cal = model.calibration
    dec = StreamDecoder()
    fw.receive(encode(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 1)))
    theta = []
    for _ in range(500):
        fw.tick()
        s = samples(dec.feed(b"".join(fw.tx)))[0]
        fw.tx.clear()
        th, thd, ph = cal.to_si(s.theta_adc, s.theta_dot_adc, s.phi_count)
        u = ctrl.update(Measurement(s.seq / 500, th, thd, ph)).u
        fw.receive(encode_command(1, s.seq, actuator_to_counts(u, 2.0), ENABLE))
        theta.append(th)
    assert theta[:50] == list(rec.theta[:50])  # bit-identical until the quantised commands tell
    assert max(abs(a - b) for a, b in zip(theta, rec.theta, strict=True)) < 5e-4  # a few ADC counts
    assert abs(theta[-1] - rec.theta[-1]) < 2e-3 and abs(theta[-1]) < 0.05  # balanced


# ---------------------------------------------------------------- configuration and effects
def test_effects_from_file_and_command_line(tmp_path):
    f = tmp_path / "mock.toml"
    f.write_text(
        'rig = "thesis"\n[effects.arm_coulomb]\nFc = 0.3\n[effects.theta_offset]\noffset = 0.01\n'
        "[device]\nrate_hz = 1000\nseed = 4\n[faults]\ncorrupt_rate = 0.001\nschedule = [\"reset@3\"]\n"
    )
    cfg = load_mock_config(f)
    assert cfg.effects.arm_coulomb.Fc == 0.3 and cfg.device.rate_hz == 1000
    assert cfg.faults.events() == [FaultEvent("reset", 3.0)]
    cfg = build_config(f, effects=["arm_coulomb.Fc=0.5", "arm_spring.k=0.02"], faults=["stall@1:20ms"])
    model = RigModel.from_config(cfg.load_rig(), cfg.effects)
    assert isinstance(model.arm_friction.dry, Coulomb) and model.arm_friction.dry.Fc == 0.5
    assert model.spring_k == 0.02 and model.theta_offset == 0.01
    assert [str(e) for e in cfg.faults.events()] == ["stall@1:20ms", "reset@3"]


def test_rig_path_relative_to_the_mock_file(tmp_path):
    from importlib import resources

    (tmp_path / "my_rig.toml").write_text(resources.files("furuta_rt.rigs").joinpath("qube_servo2.toml").read_text())
    (tmp_path / "mock.toml").write_text('rig = "my_rig.toml"\n')
    assert load_mock_config(tmp_path / "mock.toml").load_rig().name == "qube_servo2"


@pytest.mark.parametrize(
    ("effects", "message"),
    [
        (["bogus.Fc=1"], "unknown effect 'bogus'"),
        (["arm_coulomb.Fv=1"], "has no parameter 'Fv'"),
        (["arm_coulomb.Fc=-1"], "arm_coulomb.Fc"),
        (["arm_coulomb.Fc"], "name.param=value"),
        (["arm_lugre.Fc=0.3"], "arm_lugre.sigma0"),
    ],
)
def test_bad_effects_are_one_line_user_errors(effects, message):
    with pytest.raises(UserError, match=message) as err:
        build_config(effects=effects)
    assert "\n" not in str(err.value)


def test_bad_config_file_keys(tmp_path):
    f = tmp_path / "mock.toml"
    f.write_text("[device]\nrate = 500\n")
    with pytest.raises(UserError, match=r"device\.rate': unknown key"):
        load_mock_config(f)
    f.write_text('[faults]\nschedule = ["explode@1"]\n')
    with pytest.raises(UserError, match="unknown fault 'explode'"):
        load_mock_config(f)


def test_cli_bad_input_exits_2_with_one_line(capsys):
    assert main(["--pty", "--effect", "arm_coulomb.Fc=abc"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hil-mock: error: --effect") and err.count("\n") == 1
    assert main(["--fault", "stall@1"]) == 2
    assert "needs a duration" in capsys.readouterr().err
    assert main(["--rate", "20000"]) == 2
    assert "rate_hz" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("text", "event"),
    [
        ("stall@2.0:100ms", FaultEvent("stall", 2.0, 0.1)),
        ("stall@2:0.25s", FaultEvent("stall", 2.0, 0.25)),
        ("reset@3", FaultEvent("reset", 3.0)),
        ("disconnect@5", FaultEvent("disconnect", 5.0)),
        ("mute@1.5:50ms", FaultEvent("mute", 1.5, 0.05)),
    ],
)
def test_parse_fault(text, event):
    assert parse_fault(text) == event


@pytest.mark.parametrize("text", ["stall@2", "reset@3:10ms", "reset", "boom@1", "stall@-1:5ms", "stall@x:1ms"])
def test_parse_fault_rejects(text):
    with pytest.raises(ValueError):
        parse_fault(text)


def test_link_faults_corrupt_and_drop_at_the_given_rate():
    link = LinkFaults(corrupt_rate=0.01, drop_rate=0.02, seed=7)
    data = bytes(range(1, 256)) * 400  # 102 000 bytes
    out = link.tx(data)
    assert len(out) == len(data) - link.tx_dropped
    assert link.tx_dropped == pytest.approx(0.02 * len(data), rel=0.1)
    assert link.tx_corrupted == pytest.approx(0.01 * len(data), rel=0.1)
    assert LinkFaults(seed=7).tx(data) is data  # no faults: untouched
