"""Replay: re-run the observer and controller offline over a log's recorded samples."""

from furuta_rt.replay.core import ReplayResult, replay_log

__all__ = ["ReplayResult", "replay_log"]
