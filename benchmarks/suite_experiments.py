"""Look-alike pairs for the designed-experiment benchmark (scripts/bench_experiments): design → simulate → joint
diagnose.

Each case is a pair of explanations that look alike on balancing (A the truth's effect, B its look-alike, with the
parameters that make them alike on a passive recording), and the truth concealed in the simulator: A itself, or
nothing (a null case: a resolution then is a false one). Per case: a passive recording (20 s of balancing), the
experiment `experiment design` chooses for the pair, simulated on the true rig with another seed (the rig's sensor
noise, 10 kHz physics: finer than the design's 2 kHz prediction), and `diagnose` of both jointly.

``held_out``: cases not run while the joint fit, the calibrated score and the hanging family were built. Built on
(in-sample): input gain 0.8 ↔ arm inertia, balancing and hanging, and their nulls. A ``hanging`` case's experiment is
an open-loop plan about θ = π (`run --experiment` runs it in the supervisor's open_loop state).
"""

from __future__ import annotations

from dataclasses import dataclass

from furuta_rt.config import load_rig

J_THESIS = load_rig("thesis").plant.arm_inertia  # the thesis rig's arm inertia (appendix C), kg m²


@dataclass(frozen=True)
class PairCase:
    name: str
    a: dict[str, dict[str, float]]  # the effect the truth has (when not null) and the report would name
    b: dict[str, dict[str, float]]  # its look-alike
    null: bool  # the truth has neither
    seed: int
    held_out: bool
    mode: str = "balancing"  # the experiment's: "hanging" designs an open-loop plan (furuta_rt.experiment.hanging)

    @property
    def named(self) -> str:
        return next(iter(self.a))

    @property
    def rival(self) -> str:
        return next(iter(self.b))

    @property
    def truth(self) -> dict[str, dict[str, float]]:
        return {} if self.null else self.a


def _pair(name: str, a: dict, b: dict, seed: int, held_out: bool, mode: str = "balancing") -> list[PairCase]:
    return [PairCase(name, a, b, False, seed, held_out, mode),
            PairCase(f"{name} (null)", a, b, True, seed + 50, held_out, mode)]


CASES: list[PairCase] = [
    *_pair("input gain 0.8 ↔ arm inertia", {"input_gain": {"gain": 0.8}}, {"arm_inertia": {"J": J_THESIS / 0.8}},
           1, False),
    *_pair("arm inertia ×1.25 ↔ input gain", {"arm_inertia": {"J": 1.25 * J_THESIS}}, {"input_gain": {"gain": 0.8}},
           2, True),
    *_pair("arm spring ↔ arm inertia", {"arm_spring": {"k": 0.05, "phi0": 0.0}},
           {"arm_inertia": {"J": J_THESIS - 0.05 / (2 * 3.14159 / 3.0) ** 2}}, 3, True),
    *_pair("input dead band ↔ arm Coulomb", {"input_deadzone": {"width": 0.02}}, {"arm_coulomb": {"Fc": 0.02}}, 4, True),
    *_pair("arm bias ↔ input gain", {"arm_bias": {"tau": 0.02}}, {"input_gain": {"gain": 1.1}}, 5, True),
    *_pair("arm viscous ↔ arm Coulomb", {"arm_viscous": {"Fv": 0.02}}, {"arm_coulomb": {"Fc": 0.01}}, 6, True),
    *_pair("input gain 0.8 ↔ arm inertia, hanging", {"input_gain": {"gain": 0.8}}, {"arm_inertia": {"J": J_THESIS / 0.8}},
           7, False, "hanging"),
    *_pair("arm inertia ×1.25 ↔ input gain, hanging", {"arm_inertia": {"J": 1.25 * J_THESIS}},
           {"input_gain": {"gain": 0.8}}, 8, True, "hanging"),
]
