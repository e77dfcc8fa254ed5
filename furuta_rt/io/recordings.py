"""One entry point for recordings of any format: our CSV, another rig's CSV through a mapping, or a log.

``read_recording(path)`` tells MCAP from CSV by the file's first bytes; ``write_recording`` by the
output's extension (.mcap or .csv).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from furuta_rt.config import RigConfig, load_rig
from furuta_rt.errors import UserError
from furuta_rt.io.csv import read_csv, write_csv
from furuta_rt.io.mapping import CsvMapping, load_mapping, read_mapped_csv
from furuta_rt.io.mcap_log import write_recording_mcap
from furuta_rt.io.mcap_read import is_mcap, log_to_recording, read_log, require_ticks
from furuta_rt.recording import Recording


def read_recording(path: str | Path, mapping: CsvMapping | str | None = None, rig: RigConfig | None = None,
                   progress: Callable[[int, int], None] | None = None) -> Recording:
    """A Recording from an MCAP log or a CSV (``mapping``: a CsvMapping, a shipped mapping name or a
    TOML file, for other rigs' CSVs). A log's warnings (e.g. recovered after a kill) go to
    ``rec.meta["warnings"]``; ``progress(bytes_read, size)`` per chunk of a log."""
    p = Path(path)
    if is_mcap(p):
        log = require_ticks(read_log(p, timing=False, progress=progress))
        rec = log_to_recording(log)
        rec.meta["warnings"] = list(log.warnings)
        return rec
    if mapping is None:
        return read_csv(p)
    m = load_mapping(mapping) if isinstance(mapping, str) else mapping
    if rig is None and m.u.to_torque and m.rig:
        rig = load_rig(m.rig)
    return read_mapped_csv(p, m, rig)


def output_format(path: str | Path) -> str:
    """".mcap" or ".csv", from the output's extension; UserError for anything else."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in (".mcap", ".csv"):
        raise UserError(f"output {p}: unknown format {suffix or '(no extension)'!r}; use .csv or .mcap")
    return suffix


def write_recording(rec: Recording, path: str | Path, rig: RigConfig | None = None, *, extra: bool = False,
                    progress: Callable[[int, int], None] | None = None) -> Path:
    """Write ``rec`` as CSV (.csv) or as a log of ``rig`` (.mcap; ``progress(rows_done, rows)`` as it goes)."""
    p = Path(path)
    if output_format(p) == ".mcap":
        if rig is None:
            raise UserError(f"writing {p} needs the rig config (--config)")
        return write_recording_mcap(rec, p, rig, progress=progress)
    try:
        write_csv(rec, p, extra=extra)
    except OSError as err:
        raise UserError(f"cannot write {p}: {err.strerror}") from None
    return p
