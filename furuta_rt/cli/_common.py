"""Helpers shared by the subcommands."""

from __future__ import annotations

import argparse
import math

from furuta_rt.config import SHIPPED_RIGS, RigConfig, load_rig, require_plausible
from furuta_rt.errors import UserError


def add_config_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        metavar="FILE",
        default=None,
        help=f"rig TOML file, or a shipped rig: {', '.join(SHIPPED_RIGS)} (default: thesis)",
    )


def rig_from_args(args: argparse.Namespace) -> RigConfig:
    """The rig of ``--config``; an implausible plant (a unit mistake) is refused: this rig's controller
    is designed and run from it."""
    return require_plausible(load_rig(args.config), args.config or "thesis")


def parse_gains(text: str | None) -> list[float] | None:
    """'l1,l2,l3,l4' → four floats, or a UserError naming the problem."""
    if text is None:
        return None
    parts = [p for p in text.replace(" ", "").split(",") if p]
    try:
        gains = [float(p) for p in parts]
    except ValueError:
        raise UserError(f"--gains {text!r}: not four numbers separated by commas (e.g. 60,20,10,4)") from None
    if len(gains) != 4:
        raise UserError(f"--gains {text!r}: need exactly four gains l1,l2,l3,l4, got {len(gains)}")
    bad = [f"l{i + 1} = {g}" for i, g in enumerate(gains) if not math.isfinite(g)]
    if bad:
        raise UserError(f"--gains {text!r}: {', '.join(bad)} is not a finite number (e.g. 60,20,10,4)")
    return gains


def add_force_argument(parser: argparse.ArgumentParser, outputs: str,
                       when: str = "swapped in only once the new one is complete") -> None:
    """``--force``: the one way to let a command replace existing files (``outputs``: which, in words;
    ``when``: when the old ones are replaced)."""
    parser.add_argument("--force", action="store_true",
                        help=f"replace the existing {outputs} ({when}); without it an existing output file is refused "
                        "(exit 2) before any work is done")
