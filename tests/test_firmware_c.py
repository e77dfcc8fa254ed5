"""The DAQ firmware's C core (firmware_protocol/firmware) as hil_mock's device, against the Python device.

* Conformance: one scripted host session — handshake (a refused one first), device-timed sampling, a
  closed loop, stale and future COMMANDs, late answers, the watchdog and the CLEAR_FAULT rule, CONFIG
  applied and rejected, an overrun, a TX overflow, a corrupted and chopped link, UART errors, a watchdog reset,
  the old session's delayed COMMAND after the new HELLO, STOP, a hang-up, the pendulum falling onto the ADC
  rail — runs against the Python device (hil_mock.firmware) and the C
  device (hil_mock.c_firmware, the same C that is cross-compiled for the board). Every frame either device
  sends is compared byte for byte (HELLO_ACK's firmware version aside), with the actuator output of every
  tick and the plant's state at the end.
* The same C over a real pty: the pty acceptance run of tests/test_hil_mock.py (handshake, 1 s of SAMPLEs
  without a gap, the plant answering, the watchdog zeroing the actuator), and ``furuta-rt run --mock
  --mock-firmware c`` balancing.
* The C acceptance rule agrees with firmware_protocol.acceptance on the modulo-2³² edges; the core builds
  with the strict flags and uses no libc but memcpy/memset (no allocation).
"""

from __future__ import annotations

import dataclasses
import os
import random
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from test_hil_mock import done_when
from test_reliability_harness import LOCKSTEP, DaemonProcess, read_summary, traceback_free

import furuta_rt
from firmware_protocol import (
    FAULT_MASK,
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    CommandFlags,
    Config,
    Hello,
    HelloAck,
    ResetCause,
    Sample,
    Status,
    StatusFlags,
    Stop,
    StreamDecoder,
    command_accepted,
    encode,
    encode_command,
)
from firmware_protocol.hostbuild import CODEC_DIR, CORE_DIR, REQUIRED_FLAGS
from furuta_rt.model.rig import RigModel
from hil_mock.c_firmware import load_library, make_firmware
from hil_mock.config import build_config
from hil_mock.device import VirtualDevice
from hil_mock.faults import LinkFaults
from hil_mock.firmware import Firmware

ENABLE = int(CommandFlags.ENABLE)
CLEAR = int(CommandFlags.CLEAR_FAULT)
F = StatusFlags


def new_device(kind: str, rate: int = 500, rig: str | None = None, **device: object) -> Firmware:
    cfg = build_config(rig=rig, device={"rate_hz": rate, **device})
    rig = cfg.load_rig()
    return make_firmware(kind, rig, RigModel.from_config(rig, cfg.effects), cfg.device, rate)


class ScriptedHost:
    """A host whose every action depends only on what the device sent, so two devices that agree byte for byte
    receive the same bytes. ``trace`` gets one entry per device frame and one per tick (the output)."""

    def __init__(self, fw: Firmware) -> None:
        self.fw = fw
        self.dec = StreamDecoder()
        self.trace: list[object] = []
        self.samples: list[Sample] = []
        self.statuses: list[Status] = []
        self.link: LinkFaults | None = None
        self.nonce = 0  # the session every COMMAND names: the last HELLO's

    def send(self, data: bytes) -> None:
        if self.link is not None:
            data = self.link.rx(data)
        self.fw.receive(data)
        self._collect()

    def _collect(self) -> None:
        for frame in self.fw.tx:
            msg = self.dec.feed(frame)
            if msg and type(msg[0]) is HelloAck:  # the firmware version is the one field allowed to differ
                self.trace.append(dataclasses.replace(msg[0], fw_major=0, fw_minor=0, fw_patch=0))
            else:
                self.trace.append(frame)
            self.samples += [m for m in msg if type(m) is Sample]
            self.statuses += [m for m in msg if type(m) is Status]
        self.fw.tx.clear()

    def tick(self, n: int = 1) -> None:
        for _ in range(n):
            self.fw.tick()
            self._collect()
            self.trace.append(("output", self.fw.output, self.fw.streaming))

    def hello(self, schema_hash: int = SCHEMA_HASH, nonce: int = 7) -> None:
        self.nonce = nonce
        self.send(b"\x00" + encode(Hello(PROTOCOL_VERSION, schema_hash, nonce)))  # §2.1: flush a partial frame

    def answer(self, flags: int = ENABLE, gain: int = -40) -> None:
        """A proportional COMMAND on θ's ADC answering the newest SAMPLE (CLEAR_FAULT when a fault shows)."""
        s = self.samples[-1]
        counts = max(-32768, min(32767, gain * s.theta_adc))
        self.send(encode_command(self.nonce, s.seq, counts, flags | (CLEAR if s.status & FAULT_MASK else 0)))

    def balance(self, ticks: int) -> None:
        for _ in range(ticks):
            self.tick()
            self.answer()


def session(fw: Firmware) -> ScriptedHost:
    """The scripted session (see the module docstring); returns the host with its trace."""
    h = ScriptedHost(fw)
    rng = random.Random(3)
    h.tick(3)  # idle: nothing is sent
    h.send(bytes(rng.randrange(256) for _ in range(60)))  # line noise before the host speaks
    h.hello(schema_hash=SCHEMA_HASH ^ 0x100)  # refused: HELLO_ACK with the device's own identity, no streaming
    h.tick(2)
    h.hello()
    h.tick()
    h.balance(300)  # handshake, sampling, the closed loop (the STATUS of the first second comes at tick 500)
    for k in range(120):  # stale and future COMMANDs around every answer; late and double answers
        h.tick()
        seq = h.samples[-1].seq
        h.send(encode_command(h.nonce, seq + 1, 9999, ENABLE))  # answers a SAMPLE not sent yet: discarded
        if k % 7:
            h.answer()
        h.send(encode_command(h.nonce, seq - 2, -9999, ENABLE))  # older than the accepted one: discarded
        if k % 11 == 0:
            h.tick()  # no answer to this SAMPLE: COMMAND_LATE, output held
    h.tick(15)  # 30 ms without a COMMAND: the watchdog trips and zeroes the output
    h.send(encode_command(h.nonce, h.samples[-1].seq, 5000, ENABLE))  # no CLEAR_FAULT: stays zero
    h.tick()
    h.balance(40)  # CLEAR_FAULT (output zero on that tick), then ENABLE again
    h.send(encode(Config(1000, 30)))  # applied: output zero, ENABLE needed again, seq continues
    h.balance(20)
    h.send(encode(Config(0, 30)))  # rejected: CONFIG_REJECTED, old values kept
    h.balance(20)
    h.send(encode(Config(500, 20)))
    h.balance(20)
    fw.skip(3)  # the timer fired three times without the tick: TICK_OVERRUN, seq kept
    h.balance(5)
    fw.note_tx_overflow()
    h.balance(5)
    h.link = LinkFaults(0.0, 0.0, 0.004, 0.002, seed=11)  # corrupted and dropped host→device bytes
    for k in range(300):
        h.tick()
        s = h.samples[-1]
        frame = encode_command(h.nonce, s.seq, max(-32768, min(32767, -40 * s.theta_adc)), ENABLE | CLEAR)
        if k % 13 == 0:  # a COMMAND split over two ticks
            h.send(frame[:5])
            h.tick()
            h.send(frame[5:])
        elif k % 17 == 0:  # junk with an over-long run, then a truncated frame
            h.send(bytes(rng.randrange(1, 256) for _ in range(70)) + b"\x00" + frame[:-3] + b"\x00")
        else:
            h.send(frame)
    h.link = None
    fw.set_uart_errors(3, 5)  # the UART counted errors: the STATUS answering this CONFIG reports them
    h.send(encode(Config(500, 20)))
    h.balance(20)
    fw.reboot(ResetCause.WATCHDOG)  # device reset: idle, no SAMPLE until a new HELLO; the plant runs on
    h.tick(5)
    h.hello(nonce=8)  # HELLO_ACK says the watchdog reset the device
    h.tick()
    h.send(encode_command(7, 0, 20000, ENABLE))  # the old session's COMMAND, delayed: seq 0, ENABLE, discarded
    h.tick()
    h.balance(30)
    h.send(encode(Stop(0)))  # idle, output zero
    h.tick(5)
    h.hello(nonce=9)  # a new session on an idle device: the rig is put back at its initial state
    h.balance(30)
    fw.hangup()  # the host closed the port
    h.tick(3)
    h.hello(nonce=10)
    h.tick(800)  # nobody answers: the watchdog trips, the pendulum falls (onto θ's ADC rail, or θ wraps)
    h.answer(flags=ENABLE)  # CLEAR_FAULT while θ still reads the rail: ADC_OVERRANGE stays
    h.tick(3)
    return h


SENSORS = ("wrapping", "saturating")
"""The thesis rig's θ sensor reads the full turn (θ wraps at ±π); the same rig with a θ sensor that saturates."""


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, str], ScriptedHost]:
    thesis = (Path(furuta_rt.__file__).parent / "rigs" / "thesis.toml").read_text()
    assert "theta_wraps = true" in thesis
    saturating = tmp_path_factory.mktemp("rig") / "saturating.toml"
    saturating.write_text(thesis.replace("theta_wraps = true", "theta_wraps = false"))
    rigs = {"wrapping": None, "saturating": str(saturating)}
    return {(sensor, kind): session(new_device(kind, rig=rigs[sensor])) for sensor in SENSORS for kind in ("python", "c")}


@pytest.mark.parametrize("sensor", SENSORS)
def test_c_and_python_devices_send_the_same_bytes(sessions: dict[tuple[str, str], ScriptedHost], sensor: str) -> None:
    py, c = sessions[sensor, "python"], sessions[sensor, "c"]
    assert len(py.trace) > 3000
    first = next((i for i, (a, b) in enumerate(zip(py.trace, c.trace, strict=False)) if a != b), None)
    assert first is None, f"first difference at trace entry {first}: python {py.trace[first]!r}, c {c.trace[first]!r}"
    assert len(py.trace) == len(c.trace)
    assert c.fw.sim.state == py.fw.sim.state  # the same plant, driven by the same outputs
    for name in ("commands_rx", "commands_applied", "commands_discarded", "watchdog_trips", "handshakes",
                 "handshakes_refused", "samples_sent", "status_sent", "hangups", "reboots", "replacements"):
        assert getattr(c.fw, name) == getattr(py.fw, name), name
    assert (c.fw.decoder.crc_errors, c.fw.decoder.errors) == (py.fw.decoder.crc_errors, py.fw.decoder.errors)
    assert c.fw.commands_other_session == py.fw.commands_other_session == 1


@pytest.mark.parametrize("sensor", SENSORS)
def test_the_session_exercises_every_rule(sessions: dict[tuple[str, str], ScriptedHost], sensor: str) -> None:
    """The comparison above is only as good as the session: each rule and flag must have been hit."""
    host = sessions[sensor, "c"]
    fw = host.fw
    seen = 0
    for s in host.samples:
        seen |= s.status
    for flag in (F.WATCHDOG_TRIPPED, F.CRC_ERROR, F.ENABLED, F.COMMAND_LATE, F.TICK_OVERRUN, F.CONFIG_REJECTED,
                 F.TX_OVERFLOW):
        assert seen & flag, flag.name
    assert fw.handshakes == 4 and fw.handshakes_refused == 1 and fw.reboots == 1 and fw.hangups == 1
    assert fw.replacements == 3 and fw.watchdog_trips == 2  # after the reset, the STOP and the hang-up
    assert fw.commands_discarded > 200 and fw.decoder.crc_errors > 0 and fw.decoder.errors > fw.decoder.crc_errors
    acks = [m for m in host.trace if type(m) is HelloAck]
    assert [a.reset_cause for a in acks] == [ResetCause.POWER_ON] * 2 + [ResetCause.WATCHDOG] * 3
    uart = {(m.uart_overruns, m.uart_line_errors) for m in host.statuses}
    assert uart == {(0, 0), (3, 5)}  # counted from the HELLO; the reset starts the UART's counts again
    fall = host.samples[-800:]
    if sensor == "saturating":  # θ reached π: the ADC rail latches ADC_OVERRANGE, which CLEAR_FAULT cannot clear
        assert fall[-1].theta_adc == 32767 and fall[-1].status & F.ADC_OVERRANGE and fw.output == 0.0
    else:  # θ swings through ±π: the readings wrap across the whole range, never an over-range
        assert max(s.theta_adc for s in fall) > 32000 and min(s.theta_adc for s in fall) < -32000
        assert not seen & F.ADC_OVERRANGE and not fw.faults & F.ADC_OVERRANGE
    seqs = [s.seq for s in fall]
    assert seqs == list(range(seqs[0], seqs[0] + 800))  # no seq skipped, the overrun included


@pytest.mark.parametrize("kind", ["python", "c"])
def test_a_delayed_command_of_the_old_session_is_not_applied_after_a_new_hello(kind: str) -> None:
    """The replay case: the old session's COMMAND answering its SAMPLE 0 with ENABLE, delayed past a new HELLO, would
    answer the new session's SAMPLE 0 and drive the actuator. It names its session (the old HELLO's nonce): the device
    discards it — output zero, never ENABLED, and it does not feed the watchdog — and applies the new session's own."""
    h = ScriptedHost(new_device(kind, rate=1000))
    h.hello(nonce=7)
    h.tick()
    h.send(encode_command(7, 0, 20000, ENABLE))
    h.tick(2)
    assert h.fw.output > 0  # session 7 drives
    h.hello(nonce=8)  # a new session (the host restarted): output zero, seq from 0
    h.tick()
    assert h.samples[-1].seq == 0 and h.fw.output == 0.0
    for _ in range(25):  # session 7's COMMANDs keep coming, each answering the newest SAMPLE: all discarded
        h.send(encode_command(7, h.samples[-1].seq, 20000, ENABLE))
        h.tick()
        assert h.fw.output == 0.0 and not h.samples[-1].status & F.ENABLED
    assert h.samples[-1].status & F.WATCHDOG_TRIPPED  # 20 ms without a COMMAND of session 8
    assert h.fw.commands_other_session == 25
    h.send(encode_command(8, h.samples[-1].seq, 0, CLEAR))
    h.tick()
    h.send(encode_command(8, h.samples[-1].seq, 20000, ENABLE))
    h.tick()
    assert h.fw.output > 0 and h.samples[-1].status & F.ENABLED  # session 8's own COMMAND drives


@pytest.mark.parametrize("kind", ["python", "c"])
def test_watchdog_zeroes_the_output_20ms_after_the_last_command(kind: str) -> None:
    h = ScriptedHost(new_device(kind, rate=1000))
    h.hello()
    h.tick()
    for _ in range(5):
        h.send(encode_command(h.nonce, h.samples[-1].seq, 3000, ENABLE))
        h.tick()
    assert h.fw.output > 0
    h.tick(25)
    tripped = [s.seq for s in h.samples if s.status & F.WATCHDOG_TRIPPED]
    assert tripped[0] == 25 and h.fw.output == 0.0  # last COMMAND applied at tick 5, 20 ms at 1 kHz


def test_c_acceptance_rule_agrees_with_the_shared_one() -> None:
    lib = load_library()
    edges = [0, 1, 2, 5, 0x7FFFFFFF, 0x80000000, 0x80000001, 0xFFFFFFFE, 0xFFFFFFFF]
    rng = random.Random(1)
    values = edges + [rng.randrange(1 << 32) for _ in range(6)]
    n = 0
    for seq in values:
        for sent in [None, *values]:
            for acc in [None, *values]:
                want = command_accepted(seq, sent, acc)
                got = lib.host_command_accepted(seq, sent is not None, sent or 0, acc is not None, acc or 0)
                assert bool(got) == want, (seq, sent, acc)
                n += 1
    assert n == 15 * 16 * 16


def test_core_builds_strictly_and_allocates_nothing(tmp_path: Path) -> None:
    gcc = shutil.which("gcc") or "gcc"
    obj = tmp_path / "fw_core.o"
    extra = ["-Wconversion", "-Wsign-conversion", "-Wshadow", "-Wstrict-prototypes", "-Wmissing-prototypes"]
    res = subprocess.run([gcc, *REQUIRED_FLAGS, *extra, "-O2", f"-I{CORE_DIR}", f"-I{CODEC_DIR}", "-c",
                          str(CORE_DIR / "fw_core.c"), "-o", str(obj)], capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr
    nm = subprocess.run(["nm", "-u", str(obj)], capture_output=True, text=True, check=True).stdout.split()
    undefined = {s for s in nm if s != "U"}
    assert undefined <= {"memcpy", "memset", "fp_decoder_init", "fp_decoder_push", "fp_encode"} | {
        f"hal_{n}" for n in ("encoder_count", "encoder_fault", "adc_theta", "adc_theta_dot", "actuator_write",
                             "uart_write", "tick_rate", "session_started", "reset_cause", "uart_errors")}, undefined
    assert "hal_actuator_write" in undefined and "malloc" not in undefined


def test_c_device_over_a_pty_passes_the_acceptance_run() -> None:
    cfg = build_config(device={"rate_hz": 500, "initial_theta": 0.0, "firmware": "c"})
    with VirtualDevice(cfg) as dev:
        done_when(dev.port)
        assert dev.firmware.output == 0.0  # the actuator itself, after the watchdog
        st = dev.stats
        assert st.watchdog_trips >= 1 and st.commands_rx == 550 and st.crc_errors == 0 and st.samples_sent >= 560


@pytest.mark.hil
def test_furuta_rt_run_balances_with_the_c_device(tmp_path: Path) -> None:
    """`furuta-rt run --mock --mock-firmware c` (the README's main job with the C device), 3 s, the mock in lockstep
    (in real time a host stall of a few hundred ms on a loaded machine can trip the run: not the device's doing)."""
    d = DaemonProcess(["--mock", "--mock-firmware", "c", "--duration", "3", "--no-tui", LOCKSTEP,
                       "--summary-json", str(tmp_path / "summary.json")])
    rc = d.wait(timeout=120)
    assert traceback_free(d.stderr + d.stdout), d.stderr
    assert rc == 0, f"exit {rc}\n{d.stderr}\n{d.stdout}"
    out = d.stdout + d.stderr
    assert "firmware 0.3.0" in out  # the C core's HELLO_ACK (the Python device says 0.1.0)
    assert "last start: power-on" in out and "reset by its watchdog" not in out  # HELLO_ACK's reset cause
    # the device's own counts of what it received, from its STATUS, in the summary a user reads
    assert "device's receiver (its last STATUS, this session): CRC errors 0, frame errors 0, UART overruns 0" in out
    s = read_summary(tmp_path)
    assert s["device_link"] == {"crc_errors": 0, "frame_errors": 0, "uart_overruns": 0, "uart_line_errors": 0}
    # --duration is device time: a period with no tick is a SAMPLE lost on the link or skipped by the device
    missing = 3 * 500 - s["ticks"]
    assert s["end"] == "duration" and 0 <= missing <= s["seq_gaps"] + s["device_skipped_periods"], s
    assert s["balanced_s"] > s["ticks"] / 500 - 0.1, s


def test_c_device_without_a_compiler_is_one_line_exit_2(tmp_path: Path) -> None:
    """hil-mock --firmware c where the host build cannot run: one line naming the problem, exit 2, no traceback."""
    env = {**os.environ, "CC": "no-such-cc", "FURUTA_RT_BUILD_DIR": str(tmp_path)}
    res = subprocess.run([sys.executable, "-m", "hil_mock", "--firmware", "c", "--duration", "1"], env=env,
                         capture_output=True, text=True, timeout=60, check=False)
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().splitlines() == [
        "hil-mock: error: CC=no-such-cc: no such compiler, needed to build the C firmware for the host"]
    assert "serving on" not in res.stdout and not list(tmp_path.iterdir())
