"""``furuta-rt run --comp-from REPORT.json``: the arm friction a diagnosis found becomes the compensator.

The report is what ``furuta-rt diagnose --json`` writes: its ``effects`` list names the physics found in
the vocabulary of furuta_rt.model.effects. The arm's friction effects choose the mode (thesis section 7):

    arm_lugre                      → lugre     (σ0, σ1, Fc, Fs, vs, Fv; an arm_viscous found beside it adds to Fv)
    arm_stiction (+ arm_coulomb)   → stiction  (Fs breakaway, Fc sliding, Fv from arm_viscous)
    arm_coulomb                    → coulomb   (Fc, Fv from arm_viscous; ε from the configuration)
    arm_viscous alone              → coulomb   (Fc = 0, Fv)

Anything else in the report (latency, offsets, pendulum friction, …) is not compensation and is left out.
A file that is not such a report, a report of another rig, or one with no arm friction is refused
with one line (exit 2).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from furuta_rt.config import CompensationConfig, CompMode
from furuta_rt.errors import UserError
from furuta_rt.inputs import read_bounded, regular_input
from furuta_rt.model.effects import Effects

ARM_FRICTION = ("arm_coulomb", "arm_stiction", "arm_lugre", "arm_viscous")


@dataclass(frozen=True, slots=True)
class ReportCompensation:
    """The compensation a report gives: ``compensation`` (mode set) and where it came from, in words."""

    mode: CompMode
    compensation: CompensationConfig
    source: str
    warnings: tuple[str, ...] = ()


MAX_REPORT_BYTES = 64 * 1024 * 1024
"""A diagnose report is kilobytes; more is not one."""


def _load(path: str) -> dict[str, Any]:
    flag = f"--comp-from {path}"
    if Path(path).exists() or Path(path).is_symlink():
        regular_input(path, "--comp-from")  # a FIFO, a device, a link loop: one line, not a hang
    try:
        text = read_bounded(path, MAX_REPORT_BYTES, "--comp-from").decode("utf-8")
    except FileNotFoundError:
        raise UserError(f"{flag}: no such file (give the JSON that `furuta-rt diagnose LOG --json OUT.json` wrote)") from None
    except IsADirectoryError:
        raise UserError(f"{flag} is a directory; give the report's JSON file") from None
    except (OSError, UnicodeDecodeError) as err:
        reason = err.strerror if isinstance(err, OSError) else "not UTF-8 text"
        raise UserError(f"{flag}: cannot read it: {reason}") from None
    try:
        data = json.loads(text)
    except RecursionError:
        raise UserError(f"{flag}: nested too deeply to be a `furuta-rt diagnose --json` report") from None
    except ValueError as err:
        raise UserError(f"{flag}: not JSON ({err}); give the file `furuta-rt diagnose --json` wrote") from None
    if not isinstance(data, dict) or not isinstance(data.get("effects"), list):
        raise UserError(f"{flag}: not a `furuta-rt diagnose --json` report (it has no 'effects' list)")
    return data


def _effects(data: dict[str, Any], flag: str) -> Effects:
    found: dict[str, Any] = {}
    for item in data["effects"]:
        if not (isinstance(item, dict) and isinstance(item.get("name"), str) and isinstance(item.get("params"), dict)):
            raise UserError(f"{flag}: an entry of 'effects' is not {{\"name\": ..., \"params\": {{...}}}}: {item!r:.80}")
        found[item["name"]] = item["params"]
    try:
        return Effects.model_validate(found)
    except ValidationError as err:
        e = err.errors()[0]
        where = ".".join(str(x) for x in e["loc"])
        raise UserError(f"{flag}: effect {where}: {e['msg']}") from None


def _fmt(params: dict[str, float]) -> str:
    return ", ".join(f"{k} {v:.4g}" for k, v in params.items())


def compensation_from_report(path: str, base: CompensationConfig, rig_name: str) -> ReportCompensation:
    """The compensation of the run from the report at ``path`` (``base``: the rig's, for ε, v_zero, …)."""
    flag = f"--comp-from {path}"
    data = _load(path)
    report_rig = data.get("rig")
    if isinstance(report_rig, str) and report_rig and report_rig != rig_name:
        raise UserError(f"{flag}: the report diagnosed rig {report_rig!r}, this run is rig {rig_name!r}; "
                        f"its friction is another machine's (give the matching --config)")
    eff = _effects(data, flag)
    arm = {name: getattr(eff, name) for name in ARM_FRICTION if getattr(eff, name) is not None}
    if not arm:
        names = ", ".join(str(e.get("name")) for e in data["effects"]) or "none"
        raise UserError(f"{flag}: the diagnosis found no arm friction (effects: {names}); nothing to compensate "
                        "(run without --comp-from)")
    fv = eff.arm_viscous.Fv if eff.arm_viscous else 0.0
    mode: CompMode
    if eff.arm_lugre is not None:
        mode = "lugre"
        comp = base.model_copy(update={"mode": mode, "lugre": base.lugre.model_copy(
            update={**eff.arm_lugre.model_dump(), "Fv": eff.arm_lugre.Fv + fv})})
        used = {**eff.arm_lugre.model_dump(), "Fv": eff.arm_lugre.Fv + fv}
    elif eff.arm_stiction is not None:
        mode = "stiction"
        fc = eff.arm_coulomb.Fc if eff.arm_coulomb else 0.0
        used = {"Fc": fc, "Fs": eff.arm_stiction.Fs, "Fv": fv}
        comp = base.model_copy(update={"mode": mode, "stiction": base.stiction.model_copy(update=used)})
    else:
        mode = "coulomb"
        used = {"Fc": eff.arm_coulomb.Fc if eff.arm_coulomb else 0.0, "Fv": fv}
        comp = base.model_copy(update={"mode": mode, "coulomb": base.coulomb.model_copy(update=used)})
    source = f"{mode} from diagnose report {path} ({', '.join(arm)} found): {_fmt(used)}"
    warnings = []
    verdict = (data.get("equations") or {}).get("arm", {}) if isinstance(data.get("equations"), dict) else {}
    if isinstance(verdict, dict) and verdict.get("verdict") in ("partly_explained", "unexplained"):
        warnings.append(f"{path}: the report's arm equation is {verdict['verdict']}: the friction found may not be "
                        "all the arm's mismatch")
    return ReportCompensation(mode, comp, source, tuple(warnings))
