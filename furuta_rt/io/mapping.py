"""Other rigs' CSV recordings → Recording, through a column mapping (TOML).

A mapping names, for each field of a recording (t, theta, theta_dot, phi, u), the source column and
the affine map into this project's convention: value = scale·source + offset (θ = 0 upright, θ and φ
in the thesis' rotational sense, u the command: torque in N m or voltage in V), with optional angle
wrapping. Exports of ROS 2 topics have sparse rows (each row carries one topic): ``[rows] select``
names the column whose rows are samples, every other column is forward-filled from the rows before.
``[rows] resample_hz`` puts the samples on a uniform grid (angles interpolated linearly, u held).

An input that its publisher re-sends every ``republish_period`` seconds may have lost its first
message in the recording (the arm then moves up to a period before u changes). With ``onset =
"arm_motion"`` a change of u is moved back to the start of the arm's motion inside the period before
it, when the arm was at rest at the start of that period. Shipped mappings: furuta_rt/io/mappings/.
"""

from __future__ import annotations

import csv
import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from furuta_rt.config import RigConfig
from furuta_rt.errors import UserError
from furuta_rt.inputs import regular_input
from furuta_rt.model.actuator import DCMotor
from furuta_rt.recording import Recording
from furuta_rt.tomlfile import read_toml

REST_BEFORE = 0.05  # s the arm must have been still before a moved input change


def _angle(value: float | str) -> float:
    if isinstance(value, int | float):
        return float(value)
    text = value.strip().replace(" ", "")
    sign = -1.0 if text.startswith("-") else 1.0
    body = text.lstrip("+-")
    if body == "pi":
        return sign * math.pi
    if body.endswith("pi") and body[:-2]:
        return sign * float(body[:-2].rstrip("*")) * math.pi
    if body.startswith("pi/"):
        return sign * math.pi / float(body[3:])
    return float(text)


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid")


class FieldMap(_Section):
    source: str | None = Field(default=None, description="column name in the CSV")
    scale: float = 1.0
    offset: float = 0.0
    wrap: Literal["none", "pi", "start"] = Field(
        default="none",
        description="none; pi: every sample into (−π, π]; start: one 2π shift putting the first sample in (−π, π]",
    )
    initial: float | None = Field(default=None, description="value before the column's first value, or if it is absent")

    @field_validator("offset", mode="before")
    @classmethod
    def _offset(cls, v: Any) -> float:
        try:
            return _angle(v)
        except (TypeError, ValueError):
            raise ValueError(f"offset {v!r} is not a number or a multiple of pi ('pi', '-pi', 'pi/2')") from None


class InputMap(FieldMap):
    republish_period: float | None = Field(default=None, gt=0, description="s between re-sends of the same value")
    onset: Literal["message", "arm_motion"] = "message"
    motion_threshold: float = Field(default=0.005, gt=0, description="rad of arm motion that counts as moving")
    to_torque: bool = Field(default=False, description="convert volts to arm torque τ = Kt(V − Ke φ̇)/R (dc_motor rigs)")


class TimeMap(_Section):
    source: str
    scale: float = 1.0
    zero: bool = Field(default=True, description="start the recording at t = 0 (meta keeps the original start)")


class RowsMap(_Section):
    select: str | None = Field(default=None, description="samples are the rows where this column has a value")
    resample_hz: float | None = Field(default=None, gt=0)


class CsvMapping(_Section):
    name: str = "custom"
    description: str = ""
    rig: str | None = Field(default=None, description="rig config of these recordings (shipped name or file)")
    rows: RowsMap = RowsMap()
    t: TimeMap
    theta: FieldMap
    phi: FieldMap
    u: InputMap
    theta_dot: FieldMap | None = None


SHIPPED_MAPPINGS = tuple(
    sorted(p.name.removesuffix(".toml") for p in resources.files("furuta_rt.io.mappings").iterdir() if p.name.endswith(".toml"))
)


def _parse_value(text: str) -> Any:
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def load_mapping(name_or_path: str | Path, overrides: list[str] | tuple[str, ...] = ()) -> CsvMapping:
    """A shipped mapping by name (``macstepien``) or a TOML file, with ``FIELD.KEY=VALUE`` overrides
    (e.g. ``u.scale=10``, ``rows.resample_hz=1000``, ``theta.source=angle``)."""
    if str(name_or_path) not in SHIPPED_MAPPINGS and not Path(name_or_path).exists():
        shipped = ", ".join(SHIPPED_MAPPINGS)
        raise UserError(f"mapping {str(name_or_path)!r} is neither a shipped mapping ({shipped}) nor a TOML file")
    data, source = read_toml(name_or_path, kind="mapping", package="furuta_rt.io.mappings", shipped=SHIPPED_MAPPINGS)
    for item in overrides:
        key, sep, value = item.partition("=")
        parts = key.strip().split(".")
        if not sep or len(parts) != 2 or not all(parts):
            raise UserError(f"--map {item!r}: not of the form FIELD.KEY=VALUE (e.g. u.scale=10)")
        data.setdefault(parts[0], {})[parts[1]] = _parse_value(value.strip())
    try:
        return CsvMapping.model_validate(data)
    except ValidationError as err:
        first = err.errors()[0]
        loc = ".".join(str(x) for x in first["loc"])
        msg = "unknown key" if first["type"] == "extra_forbidden" else first["msg"]
        raise UserError(f"{source}: mapping key '{loc}': {msg}; see furuta_rt/io/mappings/macstepien.toml") from None


def _read_columns(path: Path, names: dict[str, str], optional: set[str], mapping: CsvMapping) -> dict[str, np.ndarray]:
    """The named source columns as float arrays (NaN where a row has no value)."""
    if path.exists() or path.is_symlink():
        regular_input(path, "recording")  # a FIFO would block, /dev/zero never ends
    try:
        fh = path.open(newline="")
    except FileNotFoundError:
        raise UserError(f"recording {path} does not exist") from None
    except OSError as err:
        raise UserError(f"cannot read {path}: {err.strerror}") from None
    with fh:
        try:
            reader = csv.reader(fh)
            header = [h.strip() for h in next(reader, [])]
            if not header:
                raise UserError(f"{path}: empty file; expected a header line")
            index: dict[str, int] = {}
            for field, col in names.items():
                if col in header:
                    index[field] = header.index(col)
                elif field not in optional:
                    shown = ", ".join(header[:8]) + (", …" if len(header) > 8 else "")
                    raise UserError(
                        f"{path}: no column {col!r} for {field} (mapping '{mapping.name}'); the file has {shown}; "
                        f"fix the mapping's [{field.split('.')[0]}] source"
                    )
            raw: dict[str, list[str]] = {f: [] for f in index}
            for row in reader:
                if not row:
                    continue
                for field, i in index.items():
                    raw[field].append(row[i] if i < len(row) else "")
        except UnicodeDecodeError:
            raise UserError(f"{path}: not a text CSV file") from None
        except csv.Error as err:
            raise UserError(f"{path}, line {reader.line_num}: {err}") from None
    out: dict[str, np.ndarray] = {}
    for field, cells in raw.items():
        try:
            out[field] = np.array([float(c) if c.strip() else math.nan for c in cells], dtype=float)
        except ValueError:
            bad = next(i for i, c in enumerate(cells) if c.strip() and not _is_number(c))
            raise UserError(
                f"{path}, line {bad + 2}, column {names[field]!r}: {cells[bad]!r} is not a number"
            ) from None
    return out


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _forward_fill(x: np.ndarray, initial: float | None) -> np.ndarray:
    valid = ~np.isnan(x)
    idx = np.where(valid, np.arange(len(x)), -1)
    np.maximum.accumulate(idx, out=idx)
    out = np.where(idx >= 0, x[np.maximum(idx, 0)], math.nan if initial is None else initial)
    return out


def _wrap(x: np.ndarray, how: str) -> np.ndarray:
    if how == "pi" and len(x):
        return np.pi - np.mod(np.pi - x, 2.0 * np.pi)  # (−π, π]
    if how == "start" and len(x):
        return x - 2.0 * np.pi * np.round(x[0] / (2.0 * np.pi))
    return x


def _move_input_onsets(t: np.ndarray, phi: np.ndarray, u: np.ndarray, m: InputMap) -> tuple[np.ndarray, list[str]]:
    """Move each change of u back to the arm's motion onset within the republish period before it."""
    notes: list[str] = []
    if m.onset != "arm_motion" or m.republish_period is None:
        return u, notes
    u = u.copy()
    changes = np.flatnonzero(np.diff(u) != 0) + 1
    previous = 0
    for i in changes:
        tc = t[i]
        j0 = max(int(np.searchsorted(t, tc - m.republish_period)), previous)
        rest = int(np.searchsorted(t, t[j0] - REST_BEFORE))
        if j0 >= i or abs(phi[j0] - phi[rest]) > m.motion_threshold:
            previous = i
            continue  # the arm was moving already: leave the change where it is
        moved = np.flatnonzero(np.abs(phi[j0:i] - phi[j0]) > m.motion_threshold)
        if len(moved):
            j = j0 + int(moved[0])
            u[j:i] = u[i]
            notes.append(f"u step to {u[i]:g} at t = {tc:.3f} s moved back to the arm's motion onset at {t[j]:.3f} s")
        previous = i
    return u, notes


def read_mapped_csv(path: str | Path, mapping: CsvMapping, rig: RigConfig | None = None) -> Recording:
    """Read another rig's CSV through ``mapping`` (``rig`` is needed only for ``u.to_torque``)."""
    p = Path(path)
    m = mapping
    fields: dict[str, FieldMap] = {"theta": m.theta, "phi": m.phi, "u": m.u}
    if m.theta_dot is not None:
        fields["theta_dot"] = m.theta_dot
    names = {"t": m.t.source} | {k: f.source for k, f in fields.items() if f.source}
    missing_source = [k for k, f in fields.items() if not f.source and f.initial is None]
    if missing_source:
        raise UserError(f"mapping '{m.name}': field {missing_source[0]} needs a source column or an initial value")
    if m.rows.select:
        names["rows.select"] = m.rows.select
    optional = {k for k, f in fields.items() if f.initial is not None}
    raw = _read_columns(p, names, optional, m)
    n_rows = len(raw["t"])
    rows = ~np.isnan(raw["rows.select"]) if m.rows.select else np.ones(n_rows, dtype=bool)
    cols: dict[str, np.ndarray] = {"t": _forward_fill(raw["t"], None)[rows] * m.t.scale}
    for k, f in fields.items():
        src = raw.get(k)
        x = np.full(n_rows, f.initial, dtype=float) if src is None else _forward_fill(src, f.initial)
        x = x[rows] * f.scale + f.offset
        if k in ("theta", "phi") and f.wrap != "none":
            x = np.unwrap(x)  # continuous for interpolation; wrapped again at the end
        cols[k] = x
    keep = np.all([~np.isnan(v) for v in cols.values()], axis=0)  # rows before every field has a value
    cols = {k: v[keep] for k, v in cols.items()}
    if len(cols["t"]) < 2:
        raise UserError(f"{p}: fewer than two rows with values for all of t, theta, phi, u (mapping '{m.name}')")
    order = np.argsort(cols["t"], kind="stable")
    t_sorted = cols["t"][order]
    unique = np.append(np.diff(t_sorted) > 0, True)  # of equal times keep the last row
    cols = {k: v[order][unique] for k, v in cols.items()}
    notes = []
    if not np.all(unique):
        notes.append(f"{int((~unique).sum())} rows with a repeated time dropped")
    t = cols["t"]
    t_start = float(t[0])
    if m.t.zero:
        t = t - t_start
    u, moved = _move_input_onsets(t, cols["phi"], cols["u"], m.u)
    notes += moved
    cols["u"] = u
    if m.rows.resample_hz:
        grid = t[0] + np.arange(int(np.floor((t[-1] - t[0]) * m.rows.resample_hz + 1e-9)) + 1) / m.rows.resample_hz
        gap = float(np.max(np.diff(t)))
        if gap > 5.0 / m.rows.resample_hz:
            notes.append(f"largest gap between samples {gap * 1e3:.0f} ms (interpolated)")
        held = np.searchsorted(t, grid, side="right") - 1
        cols = {k: v[held] if k == "u" else np.interp(grid, t, v) for k, v in cols.items() if k != "t"}
        t = grid
    else:
        cols.pop("t")
    theta = _wrap(cols["theta"], m.theta.wrap)
    phi = _wrap(cols["phi"], m.phi.wrap)
    u = cols["u"]
    if m.u.to_torque:
        a = rig.actuator if rig is not None else None
        if a is None or a.kind != "dc_motor":
            raise UserError(f"mapping '{m.name}': u.to_torque needs a dc_motor rig (give --config with Kt, R, Ke)")
        u = DCMotor(Kt=a.Kt, R=a.R, Ke=a.Ke).torque(u, np.gradient(phi, t))  # type: ignore[arg-type]
    meta: dict[str, object] = {"source": str(p), "mapping": m.name, "t_start": t_start, "notes": notes}
    if m.rig:
        meta["rig"] = m.rig
    return Recording(t=t, theta=theta, phi=phi, u=u, theta_dot=cols.get("theta_dot"), meta=meta)
