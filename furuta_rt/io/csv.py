"""The project's CSV recording format.

Columns ``t, theta, theta_dot, phi, u`` in SI (s, rad, rad/s, rad, N m; θ = 0 upright; u the torque on
the arm, or the motor voltage for a voltage-driven rig). ``theta_dot`` is optional (as measured by
the rig's analog path). Extra columns are kept in ``Recording.extra``.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from furuta_rt.errors import UserError
from furuta_rt.inputs import regular_input
from furuta_rt.recording import Recording

REQUIRED = ("t", "theta", "phi", "u")
OPTIONAL = ("theta_dot",)


def read_csv(path: str | Path, gaps: bool = False) -> Recording:
    """Read a recording; every problem is a UserError naming the file, row and column. With ``gaps``, empty or
    non-finite cells are read as NaN and time stamps need only not decrease (for a reader that repairs them, e.g.
    furuta_rt.diagnose.regression.states.prepare)."""
    p = Path(path)
    if not p.exists() and not p.is_symlink():
        raise UserError(f"recording {p} does not exist")
    regular_input(p, "recording")  # a FIFO would block, /dev/zero never ends
    try:
        with p.open(newline="") as fh:
            reader = csv.reader(fh)
            try:
                header = [h.strip() for h in next(reader)]
            except StopIteration:
                raise UserError(f"{p}: empty file; expected a header line with {', '.join(REQUIRED)}") from None
            missing = [c for c in REQUIRED if c not in header]
            if missing:
                raise UserError(
                    f"{p}: missing column(s) {', '.join(missing)}; a recording needs t, theta, phi, u "
                    "(theta_dot optional) in SI units"
                )
            rows: list[list[float]] = []
            for lineno, row in enumerate(reader, start=2):
                if not row or all(not c.strip() for c in row):
                    continue
                if len(row) != len(header):
                    raise UserError(f"{p}, line {lineno}: {len(row)} fields, the header has {len(header)}")
                values = []
                for name, cell in zip(header, row, strict=True):
                    try:
                        v = math.nan if gaps and not cell.strip() else float(cell)
                    except ValueError:
                        raise UserError(f"{p}, line {lineno}, column {name!r}: {cell!r} is not a number") from None
                    if not math.isfinite(v) and name in REQUIRED and not gaps:
                        raise UserError(f"{p}, line {lineno}, column {name!r}: {cell!r} is not finite")
                    values.append(v)
                rows.append(values)
    except UnicodeDecodeError:
        raise UserError(f"{p}: not a text CSV file") from None
    except csv.Error as err:  # a field over the csv module's limit (128 KiB), a NUL byte, ...
        raise UserError(f"{p}: not a CSV recording ({err})") from None
    except OSError as err:
        raise UserError(f"cannot read {p}: {err.strerror}") from None
    if len(rows) < 2:
        raise UserError(f"{p}: needs at least two data rows, found {len(rows)}")
    data = np.asarray(rows, dtype=float)
    cols = {name: data[:, i] for i, name in enumerate(header)}
    step = np.diff(cols["t"])
    if np.any(step < 0 if gaps else step <= 0):
        bad = int(np.argmax(step < 0 if gaps else step <= 0)) + 3
        raise UserError(f"{p}, line {bad}: time column 't' is not {'increasing' if gaps else 'strictly increasing'}")
    extra = {k: v for k, v in cols.items() if k not in REQUIRED + OPTIONAL}
    return Recording(
        t=cols["t"], theta=cols["theta"], phi=cols["phi"], u=cols["u"], theta_dot=cols.get("theta_dot"),
        extra=extra, meta={"source": str(p)},
    )


def write_csv(rec: Recording, path: str | Path, extra: bool = False) -> None:
    """Write ``rec`` in the CSV format (with ``extra`` columns appended when asked)."""
    names = ["t", "theta"] + (["theta_dot"] if rec.theta_dot is not None else []) + ["phi", "u"]
    cols = [rec.t, rec.theta] + ([rec.theta_dot] if rec.theta_dot is not None else []) + [rec.phi, rec.u]
    if extra:
        names += list(rec.extra)
        cols += list(rec.extra.values())
    data = np.column_stack(cols)
    np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt="%.9g")
