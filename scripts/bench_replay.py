"""Replay throughput: read a long daemon-like log and re-run the controller over it.

CPU time of this process is measured (the machine is shared; wall time drifts with the load).
Generates (once, cached) a simulated log as the daemon writes it (furuta_rt.replay.simulate), then
times read_log (ticks only, as `furuta-rt replay` reads) and replay_log, and prints both as multiples
of real time. Default: 10 minutes at 1 kHz (600 000 ticks, 1.8 M messages).

Run: .venv/bin/python -m scripts.bench_replay [--minutes 10] [--rate 1000] [--mode none] [--log PATH]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from furuta_rt.config import load_rig
from furuta_rt.io.mcap_read import LogData, read_log
from furuta_rt.replay import ReplayResult, replay_log
from furuta_rt.replay.simulate import simulate_log


def cached_log_path(minutes: float, rate: float, mode: str) -> Path:
    """Where the simulated log is cached (the temp dir; scripts/bench uses the same file)."""
    return Path(tempfile.gettempdir()) / f"furuta_bench_replay_{minutes:g}min_{rate:g}hz_{mode}.mcap"


def best_of(path: Path, repeat: int) -> tuple[LogData, ReplayResult, float, float]:
    """(log, replay result, best read_log CPU s, best replay_log CPU s) over ``repeat`` runs."""
    best_read = best_replay = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        log = read_log(path, timing=False, events=False)
        t1 = time.process_time()
        result = replay_log(log)
        t2 = time.process_time()
        best_read, best_replay = min(best_read, t1 - t0), min(best_replay, t2 - t1)
    return log, result, best_read, best_replay


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--mode", default="none")
    ap.add_argument("--log", type=Path, default=None, help="log to (re)use; default: a cached file in the temp dir")
    ap.add_argument("--repeat", type=int, default=3, help="take the best of this many runs")
    args = ap.parse_args()
    rig = load_rig("thesis")
    rig = rig.model_copy(update={"control": rig.control.model_copy(update={"rate_hz": args.rate})})
    path = args.log or cached_log_path(args.minutes, args.rate, args.mode)
    if not path.exists():
        t0 = time.process_time()
        simulate_log(path, rig, args.minutes * 60.0, mode=args.mode, substep_hz=args.rate, flush_every=1.0)
        print(f"generated {path} ({path.stat().st_size / 1e6:.1f} MB) in {time.process_time() - t0:.1f} s")
    log, result, best_read, best_replay = best_of(path, args.repeat)
    span = log.duration
    total = best_read + best_replay
    print(f"log: {log.n_ticks} ticks, {span:.1f} s of run, {path.stat().st_size / 1e6:.1f} MB")
    for name, secs in (("read_log (ticks)", best_read), ("replay_log", best_replay)):
        print(f"{name:18s} {secs:6.2f} s  = {span / secs:6.0f}x real time  ({secs / log.n_ticks * 1e6:.2f} us/tick)")
    print(f"read + replay:     {total:6.2f} s  = {span / total:6.0f}x real time (target >= 200x)")
    print(result.verdict())


if __name__ == "__main__":
    main()
