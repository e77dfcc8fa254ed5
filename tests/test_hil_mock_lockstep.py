"""hil-mock's compiled lockstep round (hil_mock/csrc/device.c hil_lockstep) against the reference device, over a pty.

In lockstep the default device (C firmware core, compiled plant) serves its common round in C: tick, write, plant,
wait for the COMMAND, read it. The reference is the Python firmware with the reference simulator, served by
hil_mock.device's Python loop. Lockstep is deterministic in device time, so a scripted host over a real pty must get
the same SAMPLEs from both, field for field at every tick (t_us counted from the first SAMPLE: the device clock
runs in real time until the first HELLO), and both devices must count the same — through everything that hands
the loop back to Python: a new actuator count (9 of them), the noise block handed over (2 draws a tick, 4096 a
block), a push, a stall, a friction step, the end of a session and a new one started by STOP+HELLO in one write.
"""

from __future__ import annotations

import os
import select
import threading
import time
from dataclasses import astuple, replace

import pytest
import serial

from firmware_protocol import (
    CommandFlags,
    Config,
    HelloAck,
    Sample,
    StatusFlags,
    Stop,
    StreamDecoder,
    encode,
    encode_command,
    make_hello,
    try_decode_frame,
)
from furuta_rt.runtime.hardware import SerialHardware
from hil_mock import device as hil_device
from hil_mock.config import build_config
from hil_mock.device import VirtualDevice

EFFECTS = ["arm_coulomb.Fc=0.02", "arm_stiction.Fs=0.03", "arm_viscous.Fv=0.002"]
FAULTS = ["push@0.4:2.5", "stall@0.9:20ms", "friction_step@1.5:Fc=0.01"]
SESSIONS = (2300, 400)  # SAMPLEs answered in each session (the first crosses the noise block's hand-over)
SAME_STATS = ("ticks", "samples_sent", "commands_rx", "commands_applied", "commands_discarded",
              "watchdog_trips", "crc_errors", "frame_errors", "frames_rx", "status_sent", "handshakes",
              "handshakes_refused", "hangups", "resets", "stalls", "tx_frames_dropped", "friction_steps",
              "arm_coulomb", "pushes")
"""The counters a lockstep run fixes (not late_ticks: a session's first tick follows the HELLO in real time, and is
late or not by the machine's load)."""


def counts(seq: int) -> int:
    """The host's answer to SAMPLE ``seq``: 9 levels in turn, a new one every 37 ticks."""
    return 700 * ((seq // 37) % 9 - 4)


def scripted_host(ser: serial.Serial) -> list[tuple[int, ...]]:
    """Each session: a HELLO, every SAMPLE answered at once, the last one with STOP (and the next session's HELLO in
    the same write). Returns every SAMPLE's fields, t_us from the first SAMPLE."""
    fd = ser.fileno()
    samples: list[tuple[int, ...]] = []
    hellos = [make_hello() for _ in SESSIONS]
    ser.write(b"\0" + encode(hellos[0]))
    end = time.monotonic() + 60.0
    tail = b""
    for k, n in enumerate(SESSIONS):
        got = 0
        while got < n:
            assert time.monotonic() < end, f"session {k}: {got} of {n} SAMPLEs"
            if not select.select([fd], [], [], 1.0)[0]:
                continue
            *frames, tail = (tail + os.read(fd, 65536)).split(b"\0")
            for frame in frames:
                m = try_decode_frame(frame) if frame else None
                if type(m) is not Sample:
                    continue
                samples.append((m.seq, m.t_us, m.theta_adc, m.theta_dot_adc, m.phi_count, m.status))
                got += 1
                if got < n:
                    os.write(fd, encode_command(hellos[k].nonce, m.seq, counts(m.seq), CommandFlags.ENABLE))
                else:  # the session ends; the next one starts in the same write
                    os.write(fd, encode(Stop(0)) + (encode(hellos[k + 1]) if k + 1 < len(SESSIONS) else b""))
                    break
    time.sleep(0.3)  # the device reads the last STOP, waits out its COMMAND, goes idle
    t0 = samples[0][1]
    return [(s[0], s[1] - t0, *s[2:]) for s in samples]


def serve(device: dict[str, object]) -> tuple[list[tuple[int, ...]], dict[str, object], VirtualDevice]:
    cfg = build_config(effects=EFFECTS, faults=FAULTS,
                       device={"rate_hz": 1000, "pacing": "lockstep", "priority": "normal", "seed": 3, **device})
    with VirtualDevice(cfg) as dev, serial.Serial(dev.port, timeout=0) as ser:
        samples = scripted_host(ser)
        dev.stop()
    return samples, dev.stats.as_dict(), dev


def test_compiled_lockstep_round_sends_the_reference_devices_samples_over_a_pty() -> None:
    fast, fast_stats, dev = serve({})
    ref, ref_stats, _ = serve({"firmware": "python", "plant": "python"})
    assert len(fast) == len(ref) == sum(SESSIONS)
    for k, (a, b) in enumerate(zip(fast, ref, strict=True)):
        assert a == b, f"SAMPLE {k}: compiled lockstep {a}, reference {b}"
    assert {k: fast_stats[k] for k in SAME_STATS} == {k: ref_stats[k] for k in SAME_STATS}
    # the run went where the comparison means something: both sessions, every fault, 9 actuator levels
    assert fast_stats["handshakes"] == 2 and fast_stats["pushes"] == fast_stats["stalls"] == 1
    assert fast_stats["friction_steps"] == 1 and fast_stats["arm_coulomb"] == 0.01
    assert len({s[4] for s in fast}) > 20  # the arm moved
    # and the compiled round served it: all but the ticks where Python had something to do
    ticks = fast_stats["ticks"]
    assert ref_stats["compiled_ticks"] == 0
    assert 0.9 * ticks < fast_stats["compiled_ticks"] < ticks
    # its counters reach the stats as the Python loop's do: each tick timed, one write and one wait for each COMMAND
    assert dev.timing.ticks == ticks == sum(dev.timing.histogram) and fast_stats["mean_work_us"] > 0.0
    assert fast_stats["pty_writes"] >= ticks and fast_stats["pty_selects"] >= ticks - 2
    assert fast_stats["pty_reads"] >= ticks - 2


def answer_until(port: str, stop: threading.Event, seen: list[int]) -> None:
    """A host answering every SAMPLE until ``stop``; the seq of each SAMPLE in ``seen``."""
    ser = serial.Serial(port, timeout=0)
    fd = ser.fileno()
    hello = make_hello()
    ser.write(b"\0" + encode(hello))
    tail = b""
    with ser:
        while not stop.is_set():
            try:
                if not select.select([fd], [], [], 0.05)[0]:
                    continue
                *frames, tail = (tail + os.read(fd, 65536)).split(b"\0")
            except OSError:  # the device closed the pty
                return
            for frame in frames:
                m = try_decode_frame(frame) if frame else None
                if type(m) is Sample:
                    seen.append(m.seq)
                    os.write(fd, encode_command(hello.nonce, m.seq, 0, CommandFlags.ENABLE))


@pytest.mark.parametrize("request_", ["stop", "reset", "push"])
def test_a_request_from_another_thread_reaches_the_compiled_round(request_: str) -> None:
    """stop() and the fault requests act at the next tick while the C serves the rounds: a stop ends the run at once,
    a reset restarts the device (it goes idle: the host's SAMPLEs stop coming, seq from 0 after a new HELLO), a push
    moves the pendulum and the compiled rounds go on."""
    cfg = build_config(device={"rate_hz": 1000, "pacing": "lockstep", "priority": "normal"})
    dev = VirtualDevice(cfg).start()
    halt, seen = threading.Event(), []
    host = threading.Thread(target=answer_until, args=(dev.port, halt, seen), daemon=True)
    host.start()

    def wait_for(what: str, done: object) -> None:
        deadline = time.monotonic() + 20.0
        while not done():  # type: ignore[operator]
            assert time.monotonic() < deadline and dev.running, f"{what}: {dev.stats}"
            time.sleep(0.01)

    try:
        wait_for("2000 compiled ticks", lambda: dev.stats.compiled_ticks >= 2000)
        if request_ == "stop":
            t = time.monotonic()
            dev.stop()
            assert not dev.running and time.monotonic() - t < 1.0
        elif request_ == "reset":
            dev.reset()
            wait_for("the reset", lambda: dev.stats.resets == 1)
            time.sleep(0.2)
            assert not dev.firmware.streaming and dev.firmware.seq == 0
            n = len(seen)
            time.sleep(0.2)
            assert len(seen) == n  # idle after the reset: no more SAMPLEs
        else:
            assert abs(dev.firmware.sim.theta_dot) < 50.0  # falling, swinging: never this fast on its own
            dev.push(200.0)
            wait_for("the push", lambda: dev.stats.pushes == 1)
            assert dev.firmware.sim.theta_dot > 100.0  # spinning over the top, gravity and friction aside
            ticks = dev.stats.compiled_ticks
            wait_for("compiled ticks after the push", lambda: dev.stats.compiled_ticks > ticks + 500)
    finally:
        halt.set()
        host.join(5.0)
        dev.stop()
    st = dev.stats
    assert st.ticks == dev.timing.ticks and st.compiled_ticks <= st.ticks and st.samples_sent >= len(seen)


def test_a_full_pty_hands_the_frames_the_compiled_round_could_not_write_to_the_backlog() -> None:
    """A host that answers each SAMPLE without reading it (it learns the seq from the device) fills the pty: the C's
    write comes back short, the bytes it left go to the Python loop's backlog (a SAMPLE cut mid-frame finished from
    there), frames beyond the backlog's bound are dropped and reported (TX_OVERFLOW). When the host reads again,
    every frame it gets is whole, in order, the drops are the device's count, and the C serves the rounds again."""
    cfg = build_config(device={"rate_hz": 1000, "pacing": "lockstep", "priority": "normal"})
    with VirtualDevice(cfg) as dev, serial.Serial(dev.port, timeout=0) as ser:
        fd, fw, dec = ser.fileno(), dev.firmware, StreamDecoder()
        hello = make_hello()
        ser.write(b"\0" + encode(hello))
        deadline = time.monotonic() + 20.0
        while not fw.streaming:
            assert time.monotonic() < deadline
            time.sleep(0.001)
        answered = -1
        while dev.tx_frames_dropped < 50:  # blind: the seq of the SAMPLE the device sent last, read from the device
            assert time.monotonic() < deadline, dev.stats
            seq = fw.seq - 1
            if seq > answered:
                os.write(fd, encode_command(hello.nonce, seq, 0, CommandFlags.ENABLE))
                answered = seq
        compiled_when_full = dev.compiled_ticks
        samples: list[Sample] = []
        while len(samples) < 3000 or samples[-1].seq < answered + 1000:  # read again, answer the newest SAMPLE
            assert time.monotonic() < deadline, (len(samples), dev.stats)
            if not select.select([fd], [], [], 0.2)[0]:
                continue
            new = [m for m in dec.feed(os.read(fd, 65536)) if type(m) is Sample]
            if new:
                samples += new
                os.write(fd, encode_command(hello.nonce, new[-1].seq, 0, CommandFlags.ENABLE))
        st = dev.stats
    assert dec.errors == 0  # every frame whole: the bytes after a short write went out next, none twice
    seqs = [s.seq for s in samples]
    assert seqs == sorted(set(seqs)) and seqs[0] == 0
    assert seqs[-1] + 1 - len(seqs) == st.tx_frames_dropped > 0  # what is missing is what the device dropped
    assert any(s.status & StatusFlags.TX_OVERFLOW for s in samples)
    assert st.compiled_ticks > compiled_when_full + 500  # the backlog went out, the C serves again


LONG_WAIT_S = 60.0
"""The lockstep answer wait in the tests below: a frame that comes only after it never comes within FRAME_WAIT_S."""
FRAME_WAIT_S = 20.0


def frames_until_sample(fd: int, dec: StreamDecoder) -> list[object]:
    """The frames the device sends up to and including its next SAMPLE (FRAME_WAIT_S at most)."""
    got: list[object] = []
    deadline = time.monotonic() + FRAME_WAIT_S
    while not got or type(got[-1]) is not Sample:
        left = deadline - time.monotonic()
        assert left > 0, f"no SAMPLE within {FRAME_WAIT_S:g} s: {got}"
        if select.select([fd], [], [], min(left, 0.5))[0]:
            for m in dec.feed(os.read(fd, 65536)):
                got.append(m)
                if type(m) is Sample:
                    break
    return got


def reconfiguring_host(ser: serial.Serial) -> list[tuple[object, ...]]:
    """A host that leaves a SAMPLE unanswered and then (re)configures the session, three times: the CONFIG after the
    handshake (SAMPLE 0 unanswered, as SerialHardware drops it), a CONFIG after 300 answered SAMPLEs (the compiled
    round serving by then), a HELLO after 200 more (a new session). Every other SAMPLE is answered at once. Returns
    every frame as (type name, fields), t_us from the first SAMPLE; each must come within FRAME_WAIT_S."""
    fd, dec = ser.fileno(), StreamDecoder()
    first, second = make_hello(), make_hello()
    frames: list[object] = []

    def answer(session: int, n: int) -> None:
        for _ in range(n):
            s = frames[-1]
            assert type(s) is Sample
            os.write(fd, encode_command(session, s.seq, counts(s.seq), CommandFlags.ENABLE))
            frames.extend(frames_until_sample(fd, dec))

    os.write(fd, b"\0" + encode(first))
    frames.extend(frames_until_sample(fd, dec))
    os.write(fd, encode(Config(rate_hz=1000, watchdog_ms=50)))  # SAMPLE 0 unanswered
    frames.extend(frames_until_sample(fd, dec))
    answer(first.nonce, 300)
    os.write(fd, encode(Config(rate_hz=1000, watchdog_ms=40)))  # the last SAMPLE unanswered
    frames.extend(frames_until_sample(fd, dec))
    answer(first.nonce, 200)
    os.write(fd, encode(second))  # the last SAMPLE unanswered; a new session
    frames.extend(frames_until_sample(fd, dec))
    answer(second.nonce, 100)
    os.write(fd, encode(Stop(0)))
    t0 = next(m.t_us for m in frames if type(m) is Sample)

    def fields(m: object) -> tuple[object, ...]:
        if type(m) is Sample:
            return astuple(replace(m, t_us=m.t_us - t0))
        if type(m) is HelloAck:  # the nonce is the host's, the firmware version the implementation's
            return m.sample_rate_hz, m.watchdog_ms
        return astuple(m)  # type: ignore[call-overload]

    return [(type(m).__name__, *fields(m)) for m in frames]


@pytest.fixture
def long_lockstep_wait(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(hil_device, "LOCKSTEP_TIMEOUT_S", LONG_WAIT_S)


@pytest.mark.usefixtures("long_lockstep_wait")
def test_a_hello_or_config_ends_the_lockstep_wait_for_an_earlier_samples_answer() -> None:
    """In lockstep a HELLO or a CONFIG from the host ends the device's wait for the COMMAND answering a SAMPLE sent
    before it (a host that reconfigures the session does not answer it): the next SAMPLE follows at once — here
    within FRAME_WAIT_S while the device would wait LONG_WAIT_S for the answer — and carries COMMAND_LATE, as after a
    wait in vain. The compiled round (its wait in C) and the reference Python device send the same frames."""
    runs = {}
    for name, device in (("compiled", {}), ("reference", {"firmware": "python", "plant": "python"})):
        cfg = build_config(device={"rate_hz": 1000, "pacing": "lockstep", "priority": "normal", "seed": 3, **device})
        with VirtualDevice(cfg) as dev, serial.Serial(dev.port, timeout=0) as ser:
            frames = reconfiguring_host(ser)
            time.sleep(0.2)  # the device reads the STOP
            dev.stop()
        runs[name] = (frames, dev.stats)
    (fast, fast_stats), (ref, ref_stats) = runs["compiled"], runs["reference"]
    assert fast == ref
    assert {k: getattr(fast_stats, k) for k in SAME_STATS} == {k: getattr(ref_stats, k) for k in SAME_STATS}
    samples = [f for f in fast if f[0] == "Sample"]
    late = [i for i, s in enumerate(samples) if s[-1] & StatusFlags.COMMAND_LATE]
    assert len(samples) == 2 + 300 + 1 + 200 + 1 + 100
    assert late == [1, 302]  # the SAMPLEs after the CONFIGs; a new session's SAMPLE 0 is never late
    assert [s[1] for s in samples[:2]] == [0, 1] and samples[503][1] == 0  # seq: the HELLO restarted the session
    kinds = [f[0] for f in fast]
    assert kinds.count("HelloAck") == 2 and kinds.count("Status") >= 2
    assert fast_stats.handshakes == 2 and fast_stats.commands_applied == 600
    assert fast_stats.compiled_ticks > 300  # the C's wait saw the later CONFIG and the HELLO


@pytest.mark.usefixtures("long_lockstep_wait")
@pytest.mark.parametrize("firmware", ["c", "python"])
def test_the_hosts_config_handshake_is_answered_at_once_by_a_lockstep_device(firmware: str) -> None:
    """SerialHardware's handshake with a CONFIG (the HELLO_ACK's watchdog is not the one asked for) gets its STATUS at
    once from a lockstep device waiting for the answer to SAMPLE 0, not after the device's answer wait (here far
    beyond the host's CONFIG_TIMEOUT_S)."""
    cfg = build_config(device={"rate_hz": 500, "pacing": "lockstep", "priority": "normal", "firmware": firmware})
    with VirtualDevice(cfg) as dev:
        hw = SerialHardware(dev.port)
        try:
            info = hw.handshake(500, 60)
        finally:
            hw.close()
        assert info.watchdog_ms == 60 and dev.firmware.watchdog_ms == 60
        assert dev.stats.samples_sent >= 2  # SAMPLE 0, then the one that went out with the STATUS
