"""Issue 10, item 1: a corrupted frame is never acted upon.

Scaled-down, seeded version of the 10⁶-chunk fuzz (scripts/chaos runs the long one through
scripts/fuzz_protocol, whose stream generators are reused here), plus an end-to-end check through the
daemon's own read → update → write path (SerialHardware + ControlLoop over a real pty): SAMPLE frames
that were corrupted on the wire produce no tick (no state update) and no COMMAND.
"""

from __future__ import annotations

import random

import pytest
from test_reliability_harness import load_fuzz_protocol, run_host_loop

import firmware_protocol as fp
from furuta_rt.config import load_rig
from furuta_rt.runtime.loop import TICK_RECORD
from furuta_rt.runtime.supervisor import STATE_NAMES

FUZZ = load_fuzz_protocol()
CHUNKS = 20_000
I_SEQ, I_STATE, I_THETA_ADC = TICK_RECORD.index("seq"), TICK_RECORD.index("state"), TICK_RECORD.index("theta_adc")


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_stream_decoder_fuzz_never_raises_and_returns_only_frames_sent_intact(seed: int) -> None:
    rng = random.Random(seed)
    pool = [(m, fp.encode(m)) for m in (FUZZ.random_message(rng) for _ in range(2000))]
    sent = {m for m, _ in pool}
    wires = {w for _, w in pool}
    stream, clean, corrupted = FUZZ.build_stream(rng, pool, CHUNKS * 33)  # chunks of 1..64 bytes: ~32.5 on average
    dec = fp.StreamDecoder()
    returned: list[fp.Message] = []
    pos = chunks = 0
    while pos < len(stream):
        step = rng.randint(1, 64)
        returned += dec.feed(stream[pos : pos + step])  # must never raise
        assert dec.pending <= dec.max_frame_len
        pos += step
        chunks += 1
    assert chunks >= CHUNKS * 0.95
    assert corrupted > 3000 and dec.errors > 2000, "the stream must actually contain corruption"
    assert dec.crc_errors > 500
    not_sent = [m for m in returned if m not in sent]
    assert not_sent == [], f"decoder returned messages that were never encoded: {not_sent[:3]}"
    assert all(fp.encode(m) in wires for m in returned)
    assert len(returned) >= clean, "a frame sent intact between two delimiters was lost"
    assert dec.frames_ok == len(returned)


def test_every_truncation_and_extension_of_a_sample_is_rejected() -> None:
    """Short and long variants of a valid frame (torn reads, merged frames) never decode."""
    wire = fp.encode(fp.Sample(77, 123456, -321, 45, -9999, 0x10))[:-1]
    dec = fp.StreamDecoder()
    for n in range(len(wire)):
        assert dec.feed(b"\x00" + wire[:n] + b"\x00") == []
    for extra in (b"\x01", b"\x02\x01", wire[:5]):
        assert dec.feed(b"\x00" + wire + extra + b"\x00") == []
    assert dec.feed(b"\x00" + wire + b"\x00") == [fp.Sample(77, 123456, -321, 45, -9999, 0x10)]


def _flip_data_bits(wire: bytes, rng: random.Random) -> bytes:
    """1-3 bit flips in COBS data bytes that keep the byte non-zero: the COBS structure and the length stay
    valid, so only the CRC can reject the frame."""
    b = bytearray(wire)
    code, i = set(), 0
    while i < len(wire) - 1:
        code.add(i)
        i += wire[i]
    data = [k for k in range(len(wire) - 1) if k not in code]
    for k in rng.sample(data, rng.randint(1, 3)):
        bit = rng.choice([1 << j for j in range(8) if b[k] ^ (1 << j)])
        b[k] ^= bit
    return bytes(b)


def _sample_wire(seq: int, theta_adc: int, status: int = 0) -> bytes:
    return fp.encode(fp.Sample(seq, seq * 2000, theta_adc, 0, 0, status))


def test_corrupted_samples_cause_no_tick_and_no_command_in_the_daemon_loop() -> None:
    """The daemon's SerialHardware + ControlLoop over a pty: the device sends SAMPLEs near upright, and
    every 7th one corrupted on the wire *and* poisoned (θ ≈ 1.9 rad, WATCHDOG_TRIPPED): accepting any of
    them would log its seq, trip the supervisor, or be answered by a COMMAND."""
    rig = load_rig("thesis")
    rate = rig.control.rate_hz
    rng = random.Random(5)
    fuzz_rng = random.Random(6)
    n = 400
    intact: dict[int, int] = {}
    pieces: list[bytes] = [b"\x00"]
    for seq in range(n):
        if seq % 7 == 3:
            poison = _sample_wire(seq, 20000, int(fp.StatusFlags.WATCHDOG_TRIPPED))
            # odd ones: 1-3 bit flips in COBS data bytes (caught by the CRC alone); even ones: any mutation
            bad = _flip_data_bits(poison, fuzz_rng) if seq % 2 else FUZZ.mutate(poison, fuzz_rng)
            pieces.append(bad if bad.endswith(b"\x00") else bad + b"\x00")
        else:
            theta_adc = rng.randint(-60, 60)  # |θ| < 0.006 rad: arms and balances
            intact[seq] = theta_adc
            pieces.append(_sample_wire(seq, theta_adc))
    result, sink, dev, hw = run_host_loop(pieces, link_timeout_s=0.5, rate=int(rate))
    ticks = sink.ticks()
    logged = [rec[I_SEQ] for rec in ticks]
    assert result.end == "trip" and result.trip_reason == "link_loss"  # the stream ended; nothing else tripped it
    assert set(logged) <= set(intact), f"ticks from corrupted frames: {sorted(set(logged) - set(intact))[:5]}"
    assert len(logged) >= 0.9 * len(intact), "most intact SAMPLEs became ticks"
    assert all(rec[I_THETA_ADC] == intact[rec[I_SEQ]] for rec in ticks)
    assert "balancing" in {STATE_NAMES[rec[I_STATE]] for rec in ticks}
    assert result.crc_errors + hw.decoder.errors > 0 and hw.decoder.errors >= (n // 7) * 0.9
    cmd_seqs = {c.seq for c in dev.commands}
    assert dev.commands, "the host answered the SAMPLEs"
    assert cmd_seqs <= set(intact), f"COMMANDs answering corrupted frames: {sorted(cmd_seqs - set(intact))[:5]}"
    assert any(c.flags & fp.CommandFlags.ENABLE for c in dev.commands)
    assert dev.output_zero and dev.acted[-1][0] == "stop", "the run ends with STOP, the output zero"
