"""Reading the project's TOML files (rigs, CSV mappings, mock configs): by shipped name or by path,
every problem a one-line UserError naming the file and the fix."""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

from furuta_rt.errors import UserError
from furuta_rt.inputs import read_bounded, regular_input

MAX_TOML_BYTES = 16 * 1024 * 1024
"""A rig, mapping or mock config is kilobytes; more is not one (and is not read into memory)."""


def read_toml(
    name_or_path: str | Path, *, kind: str, package: str | None = None, shipped: tuple[str, ...] = ()
) -> tuple[dict[str, Any], str]:
    """(data, source) of a shipped TOML ``<name>.toml`` in ``package`` or of a TOML file.

    ``kind`` names the file in messages ("config file", "mapping", "mock config").
    """
    text_name = str(name_or_path)
    if package is not None and text_name in shipped:
        text = resources.files(package).joinpath(f"{text_name}.toml").read_text()
        source = f"shipped {kind} '{text_name}'"
    else:
        p = Path(text_name)
        hint = f"give a TOML file or a shipped {kind}: {', '.join(shipped)}" if shipped else "give a TOML file"
        if not p.exists():
            raise UserError(f"{kind} {p} does not exist; {hint}")
        regular_input(p, kind)  # not a directory, FIFO, device or link loop
        try:
            text = read_bounded(p, MAX_TOML_BYTES, kind).decode()
        except (OSError, UnicodeDecodeError) as err:
            raise UserError(f"cannot read {kind} {p}: {getattr(err, 'strerror', None) or err}") from None
        source = str(p)
    try:
        return tomllib.loads(text), source
    except tomllib.TOMLDecodeError as err:
        raise UserError(f"{source}: not valid TOML: {err}") from None
    except RecursionError:
        raise UserError(f"{source}: nested too deeply to be a {kind}") from None
