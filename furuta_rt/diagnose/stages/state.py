"""What a diagnosis knows between its stages: one immutable State, read by each stage and returned changed.

A stage is ``Callable[[State], State]`` (furuta_rt.diagnose.engine.PIPELINE lists them in order). It never changes
the State it is given: it returns a new one through the operations below — ``noted`` (a remark for the reader),
``add`` / ``drop`` / ``replace_found`` (the effects found), ``with_result`` (an equation's model refitted) and
``reread`` (its effects read again from it), ``forget`` (look-alikes of effects moved out), and
``with_`` for a stage's own output (its windows, its look-alikes). Mappings and sequences in it are read-only, so a
stage that needs a working copy (an algorithm that updates a dict of results) makes one and hands it back.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import TYPE_CHECKING

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.regression.library import Context
from furuta_rt.diagnose.regression.selection import EquationModel
from furuta_rt.diagnose.stages.findings import EquationResult, Found, Options, found_in
from furuta_rt.recording import Recording

if TYPE_CHECKING:
    from furuta_rt.diagnose.judgement.verdict import EquationVerdict
    from furuta_rt.diagnose.stages.armlock import ArmLock
    from furuta_rt.diagnose.stages.decay import DecayResult
    from furuta_rt.diagnose.stages.gate import Gated
    from furuta_rt.diagnose.stages.onset import OnsetTiming
    from furuta_rt.diagnose.stages.stickslip import WindowStage


def frozen_map(d: Mapping | None = None) -> Mapping:
    """A read-only view of a copy of ``d``."""
    return MappingProxyType(dict(d or {}))


@dataclass(frozen=True)
class State:
    """The recording, its rig and options, and every finding so far (each stage's own output among them)."""

    rec: Recording
    rig: RigConfig
    opts: Options
    ctx: Context
    notes: tuple[str, ...] = ()
    ems: Mapping[str, EquationModel] = field(default_factory=frozen_map)  # each equation's regression
    res: Mapping[str, EquationResult] = field(default_factory=frozen_map)  # each equation's selected model
    found: tuple[Found, ...] = ()
    stick: WindowStage | None = None  # the stick–slip windows, when there are sticks
    starts: OnsetTiming | None = None  # the arm's starts from rest, when they were timed
    peak: WindowStage | None = None  # the command-peak windows, when they ran
    ambiguities: tuple[dict, ...] = ()  # look-alikes the data cannot tell apart
    lookalikes: tuple[dict, ...] = ()  # look-alikes told apart
    decay: DecayResult | None = None  # the free-decay analysis, when the recording is one
    decay_report: dict | None = None  # ... with the free swing's reading, as the report shows it
    gated: Gated | None = None  # what the prediction gate left and predicted
    below_practical: tuple[dict, ...] = ()  # effects too small to matter
    arm_lock: ArmLock | None = None  # the arm's rests against a torque, when it has any
    fit: Mapping = field(default_factory=frozen_map)  # the held-out prediction metric
    prediction: Mapping = field(default_factory=frozen_map)  # its windows, horizon and models (for figures)
    closed_loop: dict | None = None
    verdicts: Mapping[str, EquationVerdict] = field(default_factory=frozen_map)
    identification: dict | None = None

    def with_(self, **changes: object) -> State:
        """This state with a stage's outputs set (mappings are frozen, lists become tuples)."""
        fixed = {k: frozen_map(v) if isinstance(v, dict) and k in _MAPPINGS else
                 tuple(v) if isinstance(v, list) else v for k, v in changes.items()}
        return replace(self, **fixed)

    def noted(self, *notes: str) -> State:
        return replace(self, notes=(*self.notes, *notes))

    def add(self, *found: Found) -> State:
        return replace(self, found=(*self.found, *found))

    def drop(self, names: Iterable[str]) -> State:
        """Without the found effects named ``names``."""
        gone = set(names)
        return replace(self, found=tuple(f for f in self.found if f.name not in gone))

    def replace_found(self, found: Iterable[Found]) -> State:
        return replace(self, found=tuple(found))

    def with_result(self, eq: str, result: EquationResult, em: EquationModel | None = None) -> State:
        """Equation ``eq``'s model refitted (and its regression, when it was redone on other rows)."""
        ems = self.ems if em is None else frozen_map({**self.ems, eq: em})
        return replace(self, res=frozen_map({**self.res, eq: result}), ems=ems)

    def reread(self, eq: str, skip: tuple[str, ...] = (), new: tuple[str, ...] = ()) -> State:
        """The found effects of equation ``eq``'s regression read again from its refitted model (``skip``: left as
        found, e.g. a delay a window stage reports; ``new``: effects the refit added, appended); every other effect
        as it was (one a window stage replaced stays out)."""
        fresh = {f.name: f for f in found_in(self.ems[eq], self.res[eq], []) if f.name not in skip}
        kept = [fresh.get(f.name, f) if f.equation == eq and f.source == "inverse dynamics" else f for f in self.found]
        return replace(self, found=(*kept, *(fresh[n] for n in new if n in fresh)))

    def forget(self, names: Iterable[str]) -> State:
        """Without the look-alike entries of effects no longer reported (``names``: moved out by a stage)."""
        gone = set(names)
        return replace(self, ambiguities=tuple(a for a in self.ambiguities if a["effects"][0] not in gone),
                       lookalikes=tuple(a for a in self.lookalikes if a.get("reported") not in gone))

    @property
    def current(self) -> dict[str, dict[str, float]]:
        """{name: params} of the rig's own effects with the ones found so far on top."""
        return {**self.ctx.known, **{f.name: f.params for f in self.found}}


_MAPPINGS = ("ems", "res", "fit", "prediction", "verdicts")
