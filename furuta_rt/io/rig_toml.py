"""A RigConfig as TOML text (the "rig" metadata and the rig.toml attachment of a log).

The standard library reads TOML but does not write it; rig files only need tables of scalars and
lists of numbers, which this writes. ``load_rig``/``rig_from_dict`` read the text back to an equal
RigConfig (floats are written with ``repr``, so they come back bit for bit).
"""

from __future__ import annotations

import json
import math
from typing import Any

from furuta_rt.config import RigConfig


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # a JSON string is a valid TOML basic string
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} as TOML")


def _table(data: dict[str, Any], prefix: str, lines: list[str]) -> None:
    scalars = {k: v for k, v in data.items() if not isinstance(v, dict)}
    tables = {k: v for k, v in data.items() if isinstance(v, dict)}
    if prefix and (scalars or not tables):
        lines.append(f"\n[{prefix}]")
    for k, v in scalars.items():
        lines.append(f"{k} = {_value(v)}")
    for k, v in tables.items():
        _table(v, f"{prefix}.{k}" if prefix else k, lines)


def dict_to_toml(data: dict[str, Any]) -> str:
    """TOML text of nested dicts of scalars and lists (``None`` values are left out)."""

    def drop_none(d: dict[str, Any]) -> dict[str, Any]:
        return {k: drop_none(v) if isinstance(v, dict) else v for k, v in d.items() if v is not None}

    lines: list[str] = []
    _table(drop_none(data), "", lines)
    return "\n".join(lines).lstrip("\n") + "\n"


def rig_to_toml(rig: RigConfig) -> str:
    """The rig config as a TOML rig file."""
    data = rig.model_dump(mode="json", exclude_none=True)
    if rig.sensors.bessel_cutoff is None:  # TOML has no null: the config reads "none" as no θ filter
        data["sensors"]["bessel_cutoff"] = "none"
    return dict_to_toml(data)
