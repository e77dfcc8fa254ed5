"""The benchmark of `diagnose`: concealed-effect recordings of closed-loop balancing, and their scoring.

Each case is a run of furuta_rt.sim.closed_loop.run_closed_loop — the same Simulator and Controller
that hil_mock and the daemon run — on the thesis rig with sensor noise and encoder/ADC quantisation,
some with an arm-reference excitation (a slow square wave or a two-sine on φ), with effects alone, in
pairs or none, at sizes where the nominal model still looks plausible (the loop balances, nothing is
obviously wrong). Generated runs are cached on disk (they take a few seconds each).

Scoring (``score``), honest about what counts:
* an injected effect is *detected* when it is reported with its main parameter within 20 % — for
  input_gain and arm_inertia, 20 % of its departure from nominal (|ĝ − g| ≤ 0.2·|g − 1|), not of the
  value itself; *detected as look-alike* when it is the declared alternative of a reported ambiguity;
* a *false discovery* is a reported effect that was not injected, unless it is the reported half of a
  declared ambiguity whose other half was injected (for LuGre as the alternative of Coulomb + stiction, the
  reported half is both: the alternative model replaces them, ``replaced``);
* the fit *improves* when the augmented model's held-out prediction NRMSE is below the nominal one's.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import pickle
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from furuta_rt.config import RigConfig, load_rig
from furuta_rt.model.coupling import Coupling
from furuta_rt.model.effects import EFFECT_TYPES, effects_from_assignments
from furuta_rt.model.rig import calibration_from_config
from furuta_rt.model.sensors import Calibration
from furuta_rt.recording import Recording
from furuta_rt.sim.closed_loop import run_closed_loop

MAIN = {name: next(iter(cls.model_fields)) for name, cls in EFFECT_TYPES.items()}
MAIN["arm_stiction"] = "Fs"
MAIN["arm_lugre"] = "Fs"  # the breakaway (Stribeck peak); σ0, σ1 are below the encoder's resolution
RELATIVE_TO_NOMINAL = {"input_gain": 1.0}  # departure from this value is what is scored
TOLERANCE = 0.2


@dataclass(frozen=True)
class Case:
    name: str
    effects: tuple[str, ...]  # name.param=value assignments (the hil-mock --effect syntax)
    seed: int
    reference: str | None = None  # None | "square" | "sine"
    duration: float = 60.0
    rig_change: tuple[tuple[str, float], ...] = ()  # the TRUE rig's departure from the config (see true_rig)

    @property
    def injected(self) -> dict[str, dict[str, float]]:
        return effects_from_assignments(list(self.effects)).present()

    def key(self) -> str:
        text = repr((self.effects, self.seed, self.reference, self.duration, CACHE_VERSION))
        if self.rig_change:
            text += repr(self.rig_change)
        return hashlib.sha1(text.encode()).hexdigest()[:16]


CACHE_VERSION = 1


def reference_signal(kind: str | None, n: int, rate_hz: float, seed: int) -> np.ndarray | None:
    """Arm-reference excitation: a square wave (±0.3 rad, 6 s) or two sines (0.3 rad at 1/6 Hz + 0.15 rad)."""
    if kind is None:
        return None
    t = np.arange(n) / rate_hz
    phase = 0.5 * (seed % 7)
    if kind == "square":
        return 0.3 * np.sign(np.sin(2 * np.pi * t / 6.0 + phase))
    if kind == "sine":
        return 0.3 * np.sin(2 * np.pi * t / 6.0 + phase) + 0.15 * np.sin(2 * np.pi * t / 2.2 + 1.0 + phase)
    raise ValueError(f"unknown reference {kind!r}")


def cached(key: str, cache: Path | None, make: Callable[[], Recording]) -> Recording:
    """The recording stored under ``key`` in ``cache``, else ``make()`` (stored there when a cache is given)."""
    path = cache / f"{key}.pkl" if cache else None
    if path is not None and path.exists():
        with path.open("rb") as fh:
            return pickle.load(fh)
    rec = make()
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("wb") as fh:
            pickle.dump(rec, fh)
    return rec


def generate(case: Case, rig: RigConfig, cache: Path | None = None) -> Recording:
    """The case's recording (from the cache when there)."""

    def make() -> Recording:
        n = round(case.duration * rig.control.rate_hz)
        ref = reference_signal(case.reference, n, rig.control.rate_hz, case.seed)
        true, host, coupling = true_rig(rig, case.rig_change)
        rec = run_closed_loop(true, case.duration, effects=effects_from_assignments(list(case.effects)),
                              seed=case.seed, reference=ref, host_calibration=host, coupling=coupling)
        if ref is not None:
            rec.extra["phi_ref"] = ref
        rec.meta["case"] = case.name
        return rec

    return cached(case.key(), cache, make)


def true_rig(rig: RigConfig, change: tuple[tuple[str, float], ...]) -> tuple[RigConfig, Calibration | None,
                                                                           Coupling | None]:
    """(the rig the recording is made on, the host's calibration if it differs from the DAQ's, a compliant coupling)
    for a case's ``rig_change``: ("plant.<key>", factor) multiplies a plant parameter of the config;
    ("sensors.theta_scale", factor) makes the host read θ (and θ̇) as factor × the true angle (the DAQ's counts
    converted with a θ scale off by that factor: the controller sees the scaled θ); ("coupling.<field>", value) sets
    a field of a compliant rotor–arm coupling (furuta_rt.model.coupling)."""
    plant: dict[str, float] = {}
    coupling: dict[str, float] = {}
    host = None
    for key, factor in change:
        section, _, name = key.partition(".")
        if section == "plant":
            plant[name] = float(getattr(rig.plant, name)) * factor
        elif key == "sensors.theta_scale":
            cal = calibration_from_config(rig)
            host = dataclasses.replace(cal, theta_rad_per_count=cal.theta_rad_per_count * factor,
                                       theta_dot_rad_s_per_count=cal.theta_dot_rad_s_per_count * factor)
        elif section == "coupling":
            coupling[name] = factor
        else:
            raise ValueError(f"unknown rig change {key!r}")
    if plant:
        rig = rig.model_copy(update={"plant": rig.plant.model_copy(update=plant)})
    return rig, host, Coupling(**coupling) if coupling else None


def _c(name: str, seed: int, ref: str | None, *effects: str) -> Case:
    return Case(name, tuple(effects), seed, ref)


def cases() -> list[Case]:
    """The full suite: effects alone and in pairs, several seeds, null cases, with and without excitation."""
    return [
        # nulls
        _c("null", 1, None), _c("null", 2, "square"), _c("null", 3, "sine"),
        _c("null", 4, None), _c("null", 5, "square"), _c("null", 6, "sine"),
        # effects alone
        _c("arm_coulomb", 11, None, "arm_coulomb.Fc=0.02"),
        _c("arm_coulomb", 12, "sine", "arm_coulomb.Fc=0.06"),
        _c("arm_coulomb", 13, "square", "arm_coulomb.Fc=0.1"),
        _c("arm_viscous", 14, "sine", "arm_viscous.Fv=0.01"),
        _c("arm_viscous", 15, "square", "arm_viscous.Fv=0.05"),
        _c("pendulum_viscous", 16, "sine", "pendulum_viscous.bp=0.0001"),
        _c("pendulum_viscous", 17, "square", "pendulum_viscous.bp=0.0003"),
        _c("pendulum_viscous", 18, "sine", "pendulum_viscous.bp=0.0005"),
        _c("theta_offset", 19, None, "theta_offset.offset=0.005"),
        _c("theta_offset", 20, "sine", "theta_offset.offset=-0.01"),
        _c("theta_offset", 21, "square", "theta_offset.offset=0.02"),
        _c("input_delay", 22, "square", "input_delay.delay=0.002"),
        _c("input_delay", 23, "sine", "input_delay.delay=0.006"),
        _c("input_delay", 24, "sine", "input_delay.delay=0.01"),
        _c("input_gain", 25, "sine", "input_gain.gain=0.8"),
        _c("input_gain", 26, "square", "input_gain.gain=1.2"),
        _c("arm_spring", 27, "sine", "arm_spring.k=0.01", "arm_spring.phi0=0.2"),
        _c("arm_spring", 28, "square", "arm_spring.k=0.05"),
        _c("arm_inertia", 29, "sine", "arm_inertia.J=0.065"),
        _c("arm_inertia", 30, "square", "arm_inertia.J=0.035"),
        _c("arm_inertia", 31, "sine", "arm_inertia.J=0.07"),
        # pairs
        _c("arm_coulomb+arm_viscous", 41, "sine", "arm_coulomb.Fc=0.05", "arm_viscous.Fv=0.02"),
        _c("arm_coulomb+theta_offset", 42, None, "arm_coulomb.Fc=0.03", "theta_offset.offset=0.01"),
        _c("arm_coulomb+pendulum_viscous", 43, "square", "arm_coulomb.Fc=0.05", "pendulum_viscous.bp=0.0003"),
        _c("arm_viscous+arm_inertia", 44, "sine", "arm_viscous.Fv=0.03", "arm_inertia.J=0.065"),
        _c("input_delay+input_gain", 45, "square", "input_delay.delay=0.005", "input_gain.gain=0.9"),
        _c("arm_spring+theta_offset", 46, "sine", "arm_spring.k=0.03", "theta_offset.offset=0.01"),
        _c("pendulum_viscous+theta_offset", 47, "sine", "pendulum_viscous.bp=0.0002", "theta_offset.offset=-0.008"),
        _c("input_delay+arm_coulomb", 48, None, "input_delay.delay=0.004", "arm_coulomb.Fc=0.04"),
    ]


def hard_cases() -> list[Case]:
    """Harder effects, scored apart: input deadzones, pendulum Coulomb friction, an input saturation that clips 1 % of
    the commands."""
    return [
        _c("input_deadzone", 51, "sine", "input_deadzone.width=0.02"),
        _c("input_deadzone", 52, None, "input_deadzone.width=0.01"),
        _c("pendulum_coulomb", 54, "sine", "pendulum_coulomb.Fc=0.0002"),
        _c("input_saturation", 57, "square", "input_saturation.limit=0.5"),
    ]


def stiction_cases() -> list[Case]:
    """Arm stiction (eq. 2: breakaway Fs above the sliding level Fc), scored apart: Fc 0.03–0.1 N m, Fs 1.5–2 × Fc,
    without excitation (the arm parks in a stick–slip limit cycle), with a square-wave reference (it parks at the
    plateaus) and with a two-sine reference (it rarely sticks for long)."""
    return [
        _c("arm_stiction", 55, None, "arm_coulomb.Fc=0.03", "arm_stiction.Fs=0.05"),
        _c("arm_stiction", 56, "sine", "arm_coulomb.Fc=0.04", "arm_stiction.Fs=0.06"),
        _c("arm_stiction", 58, None, "arm_coulomb.Fc=0.05", "arm_stiction.Fs=0.08"),
        _c("arm_stiction", 59, "square", "arm_coulomb.Fc=0.06", "arm_stiction.Fs=0.12"),
        _c("arm_stiction", 60, "square", "arm_coulomb.Fc=0.1", "arm_stiction.Fs=0.15"),
        _c("arm_stiction", 61, "sine", "arm_coulomb.Fc=0.08", "arm_stiction.Fs=0.14"),
        _c("arm_stiction", 62, None, "arm_coulomb.Fc=0.07", "arm_stiction.Fs=0.14"),
    ]


def lugre_cases() -> list[Case]:
    """Arm LuGre friction (eq. 3: bristles σ0 = 1e4 N m/rad, σ1 = 1 N m s/rad as in the thesis rig's
    [compensation.lugre], a Stribeck peak Fs above Fc falling over vs), scored apart on Fs."""
    lugre = ("arm_lugre.sigma0=10000", "arm_lugre.sigma1=1")
    return [
        _c("arm_lugre", 63, None, *lugre, "arm_lugre.Fc=0.05", "arm_lugre.Fs=0.08", "arm_lugre.vs=0.1"),
        _c("arm_lugre", 64, "square", *lugre, "arm_lugre.Fc=0.06", "arm_lugre.Fs=0.1", "arm_lugre.vs=0.05"),
        _c("arm_lugre", 65, None, *lugre, "arm_lugre.Fc=0.04", "arm_lugre.Fs=0.1", "arm_lugre.vs=0.2"),
    ]


def outside_cases() -> list[Case]:
    """Recordings whose mismatch is outside the library: made on a TRUE rig that differs from the config
    (pendulum inertia ±20 %, pendulum length ±10 %, a 5 % θ sensor scale error in the loop, a compliant rotor–arm
    coupling), diagnosed against the config. Right answer: the equation the change acts in is `partly_explained` or
    `unexplained`, no effect is named, and the first possible cause is the change (``OUTSIDE_CAUSE``)."""
    return [
        Case("outside Jp +20%", (), 71, "sine", rig_change=(("plant.Jp", 1.2),)),
        Case("outside Jp -20%", (), 72, "square", rig_change=(("plant.Jp", 0.8),)),
        Case("outside l +10%", (), 73, "sine", rig_change=(("plant.l", 1.1),)),
        Case("outside l -10%", (), 74, "square", rig_change=(("plant.l", 0.9),)),
        Case("outside theta scale +5%", (), 75, "sine", rig_change=(("sensors.theta_scale", 1.05),)),
        Case("outside Jp +20% (no reference)", (), 76, None, rig_change=(("plant.Jp", 1.2),)),
        # a motor rotor of 2 % of the arm's inertia on a torsional spring and damper: an 8 Hz arm–rotor mode
        Case("outside compliant arm coupling", (), 77, "sine", rig_change=(
            ("coupling.rotor_inertia", 0.001), ("coupling.stiffness", 2.5), ("coupling.damping", 0.005))),
    ]


OUTSIDE_CAUSE = {"plant.Jp": "Jp", "plant.l": "l", "sensors.theta_scale": "theta_scale",  # rig change → cause key
                 "coupling.stiffness": "mode", "coupling.rotor_inertia": "compliance"}


def outside_score(case: Case, diagnosis_json: dict) -> dict:
    """An outside-the-library case: verdicts right (no equation `explained` by effects or `consistent` where the
    change acts — both when the change acts in both), false effects (any reported effect), the right cause first."""
    eqs = diagnosis_json["equations"]
    verdicts = {eq: e.get("verdict") for eq, e in eqs.items()}
    right_verdict = any(v in ("partly_explained", "unexplained") for v in verdicts.values()) and not any(
        v == "explained" for v in verdicts.values())
    want = {OUTSIDE_CAUSE[k] for k, _ in case.rig_change if k in OUTSIDE_CAUSE}
    causes = {eq: (e.get("unexplained") or {}).get("possible_causes") or [] for eq, e in eqs.items()
              if e.get("unexplained")}
    firsts = {eq: c[0]["key"] for eq, c in causes.items() if c}
    alike = {eq: {x["key"] for x in c if x is c[0] or x.get("indistinguishable_from_first")} for eq, c in causes.items()}
    return {"case": case.name, "seed": case.seed, "rig_change": [list(c) for c in case.rig_change],
            "verdicts": verdicts, "verdict_right": right_verdict,
            "false_effects": [e["name"] for e in diagnosis_json["effects"] if not rotor_inertia_seen(case, e)],
            "first_cause": firsts, "cause_right": bool(firsts) and all(k in want for k in firsts.values()),
            "cause_among_lookalikes": bool(alike) and all(want & keys for keys in alike.values() if keys),
            "summary": diagnosis_json.get("summary", "")}


def rotor_inertia_seen(case: Case, effect: dict, tolerance: float = 0.3) -> bool:
    """Whether a reported effect is a compliant coupling's rotor inertia seen below the coupling's mode, where rotor and
    arm turn together: an arm inertia J + Jr, or its look-alike, an input gain J / (J + Jr) — within ``tolerance`` of
    that departure from the config. That part of the change is library physics (the arm's inertia), not a false
    effect; what is outside the library is the mode above it."""
    jr = dict(case.rig_change).get("coupling.rotor_inertia")
    if not jr:
        return False
    J = load_rig("thesis").plant.arm_inertia
    if effect["name"] == "arm_inertia":
        got, want = effect["params"]["J"] - J, jr
    elif effect["name"] == "input_gain":
        got, want = 1.0 - effect["params"]["gain"], 1.0 - J / (J + jr)
    else:
        return False
    return abs(got - want) <= tolerance * want


def quick_cases() -> list[Case]:
    """A small subset (what CI can afford)."""
    wanted = {("null", 2), ("arm_coulomb", 12), ("theta_offset", 20), ("input_delay+input_gain", 45)}
    return [c for c in cases() if (c.name, c.seed) in wanted]


# ---------------------------------------------------------------------------------- scoring
def _error(name: str, true: dict[str, float], est: dict[str, float]) -> float:
    key = MAIN[name]
    t, e = true[key], est.get(key, np.nan)
    if name == "arm_inertia":
        ref = load_rig("thesis").plant.arm_inertia
        return abs(e - t) / abs(t - ref)
    if name in RELATIVE_TO_NOMINAL:
        return abs(e - t) / abs(t - RELATIVE_TO_NOMINAL[name])
    return abs(e - t) / abs(t)


@dataclass
class CaseScore:
    case: Case
    detected: dict[str, bool]  # injected effect → found (strict: reported itself)
    detected_lookalike: dict[str, bool]  # found as the declared alternative of an ambiguity
    errors: dict[str, float]  # main-parameter error of each injected effect found (either way)
    false: list[str]
    nominal: float
    augmented: float
    seconds: float
    reported: list[dict] = field(default_factory=list)
    ambiguities: list[dict] = field(default_factory=list)
    verdicts: dict[str, str] = field(default_factory=dict)  # equation → verdict (furuta_rt.diagnose.judgement.verdict)
    fit_verdict: str = ""  # the diagnosis's paired verdict on the held-out prediction (improved/unchanged/worse/diverges)

    @property
    def improved(self) -> bool:
        return self.augmented < self.nominal

    @property
    def expected_verdicts(self) -> dict[str, str]:
        """The right verdict per equation: `explained` where an injected effect acts, `consistent` elsewhere."""
        from furuta_rt.diagnose.regression.library import ARM, CANDIDATES, PEND

        acts = {CANDIDATES[n].equation if n in CANDIDATES else ARM for n in self.case.injected}
        return {eq: "explained" if eq in acts else "consistent" for eq in (ARM, PEND)}

    @property
    def verdicts_right(self) -> dict[str, bool]:
        return {eq: self.verdicts.get(eq) == v for eq, v in self.expected_verdicts.items() if eq in self.verdicts}

    def as_json(self) -> dict:
        return {
            "case": self.case.name, "seed": self.case.seed, "reference": self.case.reference,
            "injected": self.case.injected, "reported": self.reported, "ambiguities": self.ambiguities,
            "detected": self.detected, "detected_lookalike": self.detected_lookalike, "errors": self.errors,
            "false": self.false, "nominal": self.nominal, "augmented": self.augmented, "seconds": self.seconds,
            "verdicts": self.verdicts, "expected_verdicts": self.expected_verdicts,
            "fit_verdict": self.fit_verdict,
        }


def score(case: Case, diagnosis_json: dict, seconds: float) -> CaseScore:
    injected = case.injected
    reported = {e["name"]: e["params"] for e in diagnosis_json["effects"]}
    # an ambiguity offers a whole alternative model of its equation (companion effects refitted with it)
    alternatives = {a["alternative"]["name"]: a for a in diagnosis_json["ambiguities"]}
    chosen = [a for n, a in alternatives.items() if n in injected]
    alt_params = {k: v for a in chosen for k, v in a.get("alternative_model", {}).items()}
    detected, via_alt, errors = {}, {}, {}
    for name, true in injected.items():
        strict = _error(name, true, reported[name]) if name in reported else np.inf
        alt = _error(name, true, alt_params[name]) if name in alt_params else np.inf
        if min(strict, alt) < np.inf:
            errors[name] = min(strict, alt)
        detected[name] = strict <= TOLERANCE
        via_alt[name] = not detected[name] and alt <= TOLERANCE
    covered = {a["effects"][0] for a in chosen} | {n for a in chosen for n in a.get("replaced", [])}
    false = [n for n in reported if n not in injected and n not in covered]
    fit = diagnosis_json["fit"]
    verdicts = {eq: e["verdict"] for eq, e in diagnosis_json["equations"].items() if "verdict" in e}
    return CaseScore(case, detected, via_alt, errors, false, fit["nominal"], fit["augmented"], seconds,
                     diagnosis_json["effects"], diagnosis_json["ambiguities"], verdicts,
                     str(fit.get("verdict", "")))


def run_case(case: Case, rig: RigConfig, cache: Path | None = None, closed_loop: bool = False) -> tuple[CaseScore, dict]:
    from furuta_rt.diagnose import Options, diagnose

    rec = generate(case, rig, cache)
    t0 = time.perf_counter()
    d = diagnose(rec, rig, Options(closed_loop=closed_loop))
    seconds = time.perf_counter() - t0
    out = d.to_json()
    return score(case, out, seconds), out


def totals(scores: list[CaseScore]) -> dict:
    injected = sum(len(s.detected) for s in scores)
    strict = sum(sum(s.detected.values()) for s in scores)
    alt = sum(sum(s.detected_lookalike.values()) for s in scores)
    nulls = [s for s in scores if not s.case.effects]
    with_effect = [s for s in scores if s.case.effects]
    errs = [e for s in scores for e in s.errors.values()]
    return {
        "cases": len(scores), "effects_injected": injected,
        "detected": strict, "detected_incl_lookalike": strict + alt,
        "detection_rate": strict / injected if injected else float("nan"),
        "detection_rate_incl_lookalike": (strict + alt) / injected if injected else float("nan"),
        "false_discoveries": sum(len(s.false) for s in scores),
        "false_discoveries_null_cases": sum(len(s.false) for s in nulls),
        "cases_with_false": sum(bool(s.false) for s in scores),
        "false_alarm_rate": sum(bool(s.false) for s in scores) / len(scores) if scores else float("nan"),
        "null_cases": len(nulls),
        "fit_improved": sum(s.improved for s in with_effect), "cases_with_effect": len(with_effect),
        "fit_verdicts": {v: sum(s.fit_verdict == v for s in with_effect) for v in ("improved", "unchanged", "worse", "diverges")},
        "median_param_error": float(np.median(errs)) if errs else float("nan"),
        "max_param_error": float(np.max(errs)) if errs else float("nan"),
        "median_seconds": float(np.median([s.seconds for s in scores])) if scores else float("nan"),
        "max_seconds": float(np.max([s.seconds for s in scores])) if scores else float("nan"),
        "verdicts_right": sum(sum(s.verdicts_right.values()) for s in scores),
        "verdicts": sum(len(s.verdicts_right) for s in scores),
        "null_equations_consistent": sum(v == "consistent" for s in nulls for v in s.verdicts.values()),
        "null_equations": sum(len(s.verdicts) for s in nulls),
    }


def rates(detected: int, injected: int, cases_with_false: int, cases: int) -> str:
    """The detection rate and the false-alarm rate side by side, as every benchmark group prints them: detection =
    injected effects named (main parameter within 20 %) over those injected; false alarm = cases where at least one
    effect that was not injected is named, over the cases."""
    det = (f"detection {detected}/{injected} = {100 * detected / injected:.0f} %" if injected else
           "detection n/a (nothing injected)")
    fa = f"false alarms {cases_with_false}/{cases} cases = {100 * cases_with_false / cases:.0f} %" if cases else "no cases"
    return f"{det}; {fa}"


def write_json(path: Path, scores: list[CaseScore], extra: dict | None = None) -> None:
    path.write_text(json.dumps({"cases": [s.as_json() for s in scores], "totals": totals(scores), **(extra or {})},
                               indent=1, default=float))


# ------------------------------------------------------------------------ the realistic group
REALISTIC_CACHE_VERSION = 1
# the arm damping of each shape's true rig: Quanser's courseware Dr for the QUBE, the authors' fitted b1 for macstepien
REALISTIC_ARM_VISCOUS = {"qube_servo2": 0.0015, "macstepien": 0.0117}
COMBINED = ("input_gain", "arm_inertia", "arm_viscous")  # scored through the identifiable combinations
LATENCY = ("command_latency", "input_delay")


@dataclass(frozen=True)
class RealisticCase:
    """A recording of a voltage-driven rig shaped like ``shape`` (a shipped rig), whose true physics is ``effects``
    on top of it and whose command acts ``latency_ticks`` after the sample (the config says its
    ``command_delay_ticks``), driven by ``excitation`` (benchmarks.suite_realistic)."""

    name: str
    shape: str
    excitation: str  # sine | chirp | step | swingup | balance
    effects: tuple[str, ...]
    latency_ticks: float
    seed: int
    duration: float = 30.0
    held_out: bool = False

    @property
    def reference(self) -> str:
        return self.excitation

    @property
    def injected(self) -> dict[str, dict[str, float]]:
        return effects_from_assignments(list(self.effects)).present()

    def key(self) -> str:
        text = repr(("realistic", self.shape, self.excitation, self.effects, self.latency_ticks, self.seed,
                     self.duration, REALISTIC_CACHE_VERSION))
        return hashlib.sha1(text.encode()).hexdigest()[:16]


def _r(shape: str, excitation: str, seed: int, gain: float, j_factor: float, latency: float, *extra: str,
       held_out: bool = False, duration: float = 30.0) -> RealisticCase:
    """A realistic case: torque per volt × ``gain``, arm inertia × ``j_factor``, the shape's arm damping, a total
    latency of ``latency`` ticks (a ``command_latency`` effect where it differs from the config's), and ``extra``."""
    nominal = load_rig(shape)
    J = float(f"{j_factor * nominal.plant.arm_inertia:.4g}")
    effects = [f"input_gain.gain={gain}", *([f"arm_inertia.J={J}"] if j_factor != 1.0 else []),
               f"arm_viscous.Fv={REALISTIC_ARM_VISCOUS[shape]}", *extra]
    if latency != nominal.control.command_delay_ticks:
        effects.append(f"command_latency.delay={latency / nominal.control.rate_hz:.6g}")
    tags = "+".join(dict.fromkeys(e.split(".")[0] for e in extra))
    name = f"{shape}/{excitation}" + (f"+{tags}" if tags else "")
    return RealisticCase(name, shape, excitation, tuple(effects), float(latency), seed, duration, held_out)


def realistic_cases() -> list[RealisticCase]:
    """Voltage-driven DC-motor rigs shaped like the QUBE-Servo 2 and the macstepien rig: torque per volt ×0.3…×10,
    arm inertia ×0.5…×2, latency 0–3 ticks from the config's 1, open-loop sine/chirp/step excitation with the
    pendulum hanging, swing-ups and balancing, encoder θ, arm bias, a cable spring with Coulomb friction, and one
    short single step from rest shaped like the real macstepien recordings.
    The first eleven are the in-sample part (looked at while building); the ``held_out`` ones (other seeds, sizes
    and combinations) are listed and printed apart and are not tuned on. Held-out cases that a fix was made on are
    in the in-sample part and marked so (201, 205, 211 and 401); 207–214 are the held-out set that replaces them (213
    and 214 not looked at while the arm-starts stage, furuta_rt.diagnose.stages.onset, was built on 211 and 401)."""
    spring = ("arm_spring.k=0.002", "arm_spring.phi0=0.1", "arm_coulomb.Fc=0.002")
    spring_m = ("arm_spring.k=0.01", "arm_spring.phi0=-0.2", "arm_coulomb.Fc=0.006")
    return [
        _r("qube_servo2", "sine", 101, 3.0, 1.5, 1),
        _r("qube_servo2", "chirp", 102, 0.5, 0.7, 2, *spring),
        _r("qube_servo2", "step", 103, 5.0, 1.0, 0),
        _r("qube_servo2", "swingup", 104, 2.0, 1.3, 3, "pendulum_viscous.bp=2e-05"),
        _r("qube_servo2", "balance", 105, 1.5, 0.6, 1, "arm_bias.tau=0.0005"),
        _r("macstepien", "step", 106, 7.0, 0.5, 2),
        _r("macstepien", "sine", 107, 10.0, 1.0, 1, "arm_bias.tau=0.003"),
        _r("macstepien", "swingup", 108, 7.0, 0.5, 2, "pendulum_viscous.bp=1.8e-05"),
        _r("macstepien", "chirp", 109, 0.3, 2.0, 4, *spring_m),
        _r("macstepien", "balance", 110, 3.0, 1.2, 0),
        _r("macstepien", "single_step", 111, 7.0, 0.5, 1, duration=5.0),  # shaped like the real step recordings
        _r("qube_servo2", "sine", 201, 8.0, 0.8, 2.5),  # in-sample: a fix was made on it
        _r("macstepien", "balance", 205, 0.7, 0.8, 1.5, "arm_bias.tau=-0.002"),  # likewise
        # held out
        _r("qube_servo2", "swingup", 202, 1.2, 1.8, 1, "arm_bias.tau=0.0004", held_out=True),
        _r("qube_servo2", "chirp", 203, 2.0, 0.5, 1, "pendulum_viscous.bp=1e-05", held_out=True),
        _r("macstepien", "step", 204, 4.0, 1.5, 3, held_out=True),
        _r("macstepien", "sine", 206, 6.0, 0.6, 0, *spring_m, held_out=True),
        _r("qube_servo2", "step", 207, 0.4, 1.6, 2, "arm_bias.tau=-0.0003", held_out=True),
        _r("macstepien", "chirp", 208, 5.0, 0.7, 0, held_out=True),
        _r("qube_servo2", "balance", 209, 2.5, 1.2, 3, held_out=True),
        _r("macstepien", "swingup", 210, 0.5, 1.4, 1, "pendulum_viscous.bp=3e-05", held_out=True),
        _r("qube_servo2", "single_step", 211, 12.0, 0.6, 1.5, duration=6.0),  # in-sample since the arm-starts stage
        _r("qube_servo2", "single_step", 213, 4.0, 1.3, 3, duration=6.0, held_out=True),
        _r("macstepien", "single_step", 214, 9.0, 1.0, 0, duration=6.0, held_out=True),
        _r("macstepien", "sine", 212, 1.8, 1.0, 2.5, "arm_bias.tau=0.001", held_out=True),
    ] + gross_gain_cases()


# ------------------------------------------------------------- realistic: gross torque-per-volt errors (helper realgain)
def gross_gain_cases() -> list[RealisticCase]:
    """Torque per volt ×0.1 and ×30…×70 the datasheet's (a driver's gain, a current or velocity mode, a command in
    per-unit: the real macstepien 0.1 / 0.575 files spin the arm ~10× faster per unit than its volt files), on steps of
    several levels and on one step from rest (a two-level command: only gain/damping through the speed per volt, no
    kink of the command map, can be read there). Named "… gross×g"; the first five in-sample, the last two held out
    (generated once, not tuned on; 401 is in-sample: a fix was made on it)."""
    cases = [
        (_r("macstepien", "single_step", 301, 50.0, 1.0, 1, duration=6.0), 50),
        (_r("macstepien", "step", 302, 0.1, 1.0, 1), 0.1),
        (_r("qube_servo2", "step", 303, 30.0, 1.0, 1), 30),
        (_r("qube_servo2", "single_step", 304, 0.1, 1.5, 1, duration=6.0), 0.1),
        (_r("macstepien", "sine", 305, 70.0, 0.5, 1), 70),
        # held out
        (_r("macstepien", "single_step", 401, 60.0, 0.7, 2, duration=8.0), 60),  # in-sample since the arm-starts stage
        (_r("qube_servo2", "step", 402, 0.15, 1.3, 1, held_out=True), 0.15),
    ]
    return [dataclasses.replace(c, name=f"{c.name} gross×{g:g}") for c, g in cases]


def generate_realistic(case: RealisticCase, cache: Path | None = None) -> Recording:
    """The case's recording (from the cache when there)."""
    from benchmarks.suite_realistic import simulate

    def make() -> Recording:
        rec = simulate(load_rig(case.shape), case.shape, effects_from_assignments(list(case.effects)),
                       case.excitation, case.duration, case.seed)
        rec.meta["case"] = case.name
        return rec

    return cached(case.key(), cache, make)


def arm_combinations(rig: RigConfig, gain: float, J: float, Fv: float) -> dict[str, float]:
    """The identifiable combinations of a voltage-driven arm: the steady speed per volt g·(Kt/R)/(Kt·Ke/R + Fv)
    (rad/s per V) and the time constant β/(Kt·Ke/R + Fv) (s; β the arm row's inertia with the arm's J)."""
    a = rig.actuator
    d = a.Kt * a.Ke / a.R + Fv  # type: ignore[operator]
    beta = rig.lumped().beta - rig.plant.arm_inertia + J
    return {"speed_per_volt": gain * a.Kt / a.R / d, "time_constant": beta / d}  # type: ignore[operator]


def _reported_arm(rig: RigConfig, reported: dict[str, dict[str, float]],
                  identification: dict | None = None) -> tuple[float, float, float]:
    """(gain, J, Fv) of the arm as the diagnosis reports it: its jointly calibrated ``identification.parameters`` (the
    joint fit's values) when it has them, else its effects (the config's values where none is reported)."""
    g = reported.get("input_gain", {}).get("gain", 1.0)
    J = reported.get("arm_inertia", {}).get("J", rig.plant.arm_inertia)
    Fv = reported.get("arm_viscous", {}).get("Fv", 0.0)
    par = (identification or {}).get("parameters") or {}
    if all(k in par for k in ("input_gain", "arm_inertia", "arm_viscous")) and not (identification or {}).get("unphysical"):
        # the joint fit's values (all three free): a parameter the effects report carries its joint value apart
        g, J, Fv = (float(par[k].get("joint", par[k])["value"]) for k in ("input_gain", "arm_inertia", "arm_viscous"))
    return g, J, Fv


def score_realistic(case: RealisticCase, diagnosis_json: dict, seconds: float) -> CaseScore:
    """Score like ``score``: the arm's gain, inertia and damping (as calibrated in ``identification``, else as
    reported effects) through the identifiable combinations of ``arm_combinations`` (within 20 %),
    every other injected effect by its main parameter (within 20 %), the latency within half a tick where it differs
    from the config; a false discovery is a reported effect not injected (a latency reported where there is none
    counts when it is more than half a tick off the config's)."""
    rig = load_rig(case.shape)
    injected = case.injected
    reported = {e["name"]: e["params"] for e in diagnosis_json["effects"]}
    detected: dict[str, bool] = {}
    errors: dict[str, float] = {}
    g, J, Fv = _reported_arm(rig, injected)
    true = arm_combinations(rig, g, J, Fv)
    est = arm_combinations(rig, *_reported_arm(rig, reported, diagnosis_json.get("identification")))
    for name, value in true.items():
        errors[name] = abs(est[name] - value) / abs(value)
        detected[name] = errors[name] <= TOLERANCE
    for name, params in injected.items():
        if name in COMBINED or name in LATENCY:
            continue
        key = MAIN[name]
        if name in reported:
            errors[name] = abs(reported[name][key] - params[key]) / abs(params[key])
        detected[name] = errors.get(name, np.inf) <= TOLERANCE
    h = 1.0 / rig.control.rate_hz
    configured = rig.control.command_delay_ticks * h
    true_latency = case.latency_ticks * h
    if "command_latency" in reported:
        est_latency = reported["command_latency"]["delay"]
    else:
        est_latency = configured + reported.get("input_delay", {}).get("delay", 0.0)
    false = [n for n in reported if n not in injected and n not in COMBINED and n not in LATENCY]
    if abs(true_latency - configured) > 1e-9:
        errors["latency"] = abs(est_latency - true_latency) / h  # in ticks
        detected["latency"] = errors["latency"] < 0.5
    elif abs(est_latency - configured) > 0.5 * h:
        false.append("command_latency")
    alternatives = {a["alternative"]["name"]: a for a in diagnosis_json.get("ambiguities", [])}
    covered = {a["effects"][0] for n, a in alternatives.items() if n in injected}
    false = [n for n in false if n not in covered]
    fit = diagnosis_json["fit"]
    return CaseScore(case, detected, dict.fromkeys(detected, False), errors, false, fit["nominal"],  # type: ignore[arg-type]
                     fit["augmented"], seconds, diagnosis_json["effects"], diagnosis_json.get("ambiguities", []))


def run_realistic(case: RealisticCase, cache: Path | None = None, closed_loop: bool = False) -> tuple[CaseScore, dict]:
    """Generate with the true rig, diagnose against the nominal config (``case.shape``), score."""
    from furuta_rt.diagnose import Options, diagnose

    rec = generate_realistic(case, cache)
    t0 = time.perf_counter()
    d = diagnose(rec, load_rig(case.shape), Options(closed_loop=closed_loop))
    seconds = time.perf_counter() - t0
    out = d.to_json()
    return score_realistic(case, out, seconds), out
