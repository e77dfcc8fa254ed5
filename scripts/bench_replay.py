"""Replay throughput: read a long daemon-like log and re-run the controller over it.

CPU time of the thread that reads and replays is measured (the machine is shared; wall time drifts with the
load). Not the process's: the controller design's scipy calls wake OpenBLAS's worker thread, which then spins
for a while (~0.03 s of CPU) beside a replay it takes no part in.
Generates (once, cached) a simulated log as the daemon writes it (furuta_rt.replay.simulate), then
times read_log (ticks only, as `furuta-rt replay` reads) and replay_log, and prints both as multiples
of real time. Default: 10 minutes at 1 kHz (600 000 ticks). ``--json-ticks`` also times the same log in the
layout written before /furuta/tick_batch (JSON ticks only; a copy, cached beside it): older logs' speed.

Run: .venv/bin/python -m scripts.bench_replay [--minutes 10] [--rate 1000] [--mode none] [--log PATH] [--json-ticks]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from furuta_rt.config import load_rig
from furuta_rt.io import log_schema as ls
from furuta_rt.io.mcap_read import LogData, read_log
from furuta_rt.replay import ReplayResult, replay_log
from furuta_rt.replay.simulate import simulate_log

TARGET_X = 200.0  # replay (read + re-run) at least 200× real time on a 1 kHz log


def cached_log_path(minutes: float, rate: float, mode: str) -> Path:
    """Where the simulated log is cached (the temp dir; scripts/bench uses the same file). The name says the
    layout (tick batches), so a cache written by an older version is not measured in its place."""
    return Path(tempfile.gettempdir()) / f"furuta_bench_replay_{minutes:g}min_{rate:g}hz_{mode}_batched.mcap"


def generate(path: Path, minutes: float, rate: float, mode: str) -> float:
    """Write the simulated log (as the daemon would, a chunk ended every second); CPU seconds taken."""
    rig = load_rig("thesis")
    rig = rig.model_copy(update={"control": rig.control.model_copy(update={"rate_hz": rate})})
    t0 = time.process_time()
    simulate_log(path, rig, minutes * 60.0, mode=mode, substep_hz=rate, flush_every=1.0)  # type: ignore[arg-type]
    return time.process_time() - t0


def json_ticks_copy(path: Path) -> Path:
    """``path`` without its /furuta/tick_batch channel — the layout logs had before it (JSON ticks only) — cached
    beside it; every other record copied as it is."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    out = path.with_name(path.stem + "_json_ticks.mcap")
    if out.exists() and out.stat().st_mtime >= path.stat().st_mtime:
        return out
    tmp = out.with_suffix(".part")
    with path.open("rb") as src, tmp.open("wb") as dst:
        reader = make_reader(src)
        header = reader.get_header()
        w = Writer(dst, chunk_size=256 * 1024, compression=CompressionType.ZSTD)
        w.start(profile=header.profile, library=header.library)
        for m in reader.iter_metadata():
            w.add_metadata(m.name, dict(m.metadata))
        for a in reader.iter_attachments():
            w.add_attachment(create_time=a.create_time, log_time=a.log_time, name=a.name, media_type=a.media_type,
                             data=a.data)
        ids: dict[int, int] = {}
        schema_ids: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.topic == ls.TICK_BATCH_TOPIC:
                continue
            if channel.id not in ids:
                if schema is not None and schema.id not in schema_ids:
                    schema_ids[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
                sid = schema_ids.get(schema.id, 0) if schema is not None else 0
                ids[channel.id] = w.register_channel(channel.topic, channel.message_encoding, sid, dict(channel.metadata))
            w.add_message(ids[channel.id], message.log_time, message.data, message.publish_time, message.sequence)
        w.finish()
    tmp.replace(out)
    return out


def best_of(path: Path, repeat: int) -> tuple[LogData, ReplayResult, float, float]:
    """(log, replay result, best read_log CPU s, best replay_log CPU s) over ``repeat`` runs."""
    return best_of_each([path], repeat)[0]


def best_of_each(paths: list[Path], repeat: int) -> list[tuple[LogData, ReplayResult, float, float]]:
    """``best_of`` for several logs, their runs taken in turn (one of each per round): a busy spell of the shared
    machine slows all of them alike, so their ratio is a same-run comparison."""
    best = [[float("inf"), float("inf")] for _ in paths]
    last: list[tuple[LogData, ReplayResult]] = [None] * len(paths)  # type: ignore[list-item]
    for _ in range(repeat):
        for k, path in enumerate(paths):
            t0 = time.thread_time()
            log = read_log(path, timing=False, events=False)
            t1 = time.thread_time()
            result = replay_log(log)
            t2 = time.thread_time()
            best[k] = [min(best[k][0], t1 - t0), min(best[k][1], t2 - t1)]
            last[k] = (log, result)
    return [(log, result, read, rerun) for (log, result), (read, rerun) in zip(last, best, strict=True)]


def report(path: Path, repeat: int) -> None:
    log, result, best_read, best_replay = best_of(path, repeat)
    span = log.duration
    total = best_read + best_replay
    layout = "tick batches" if log.tick_batches else "JSON ticks (the layout before tick batches)"
    print(f"log: {log.n_ticks} ticks, {span:.1f} s of run, {path.stat().st_size / 1e6:.1f} MB, {layout}")
    for name, secs in (("read_log (ticks)", best_read), ("replay_log", best_replay)):
        print(f"{name:18s} {secs:6.2f} s  = {span / secs:6.0f}x real time  ({secs / log.n_ticks * 1e6:.2f} us/tick)")
    print(f"read + replay:     {total:6.2f} s  = {span / total:6.0f}x real time (target >= {TARGET_X:g}x)")
    print(result.verdict())


def main() -> None:
    import os

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--mode", default="none")
    ap.add_argument("--log", type=Path, default=None, help="log to (re)use; default: a cached file in the temp dir")
    ap.add_argument("--repeat", type=int, default=5, help="take the best of this many runs (as scripts/bench)")
    ap.add_argument("--json-ticks", action="store_true", help="also time the log in the layout before tick batches")
    args = ap.parse_args()
    path = args.log or cached_log_path(args.minutes, args.rate, args.mode)
    if not path.exists():
        secs = generate(path, args.minutes, args.rate, args.mode)
        print(f"generated {path} ({path.stat().st_size / 1e6:.1f} MB) in {secs:.1f} s")
    print("load average (1, 5, 15 min): " + " ".join(f"{x:.2f}" for x in os.getloadavg()))
    report(path, args.repeat)
    if args.json_ticks:
        report(json_ticks_copy(path), args.repeat)


if __name__ == "__main__":
    main()
