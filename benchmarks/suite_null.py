"""Null recordings with sensor noise the config does not state, for the specificity benchmark
(scripts/bench_null) and tests: nothing is concealed in the physics, so every equation should read `consistent`.

From the two independent simulators, with the noise inside the loop (the controller sees it, as on a rig):

* thesis rig (benchmarks.suite_independent, Bessel θ path), diagnosed against the shipped thesis config:
  ``prefilter`` — white noise entering *before* the analog Bessel filter (a potentiometer and its wiring), plus the
  stated ADC noise; ``coloured`` — first-order low-passed noise (corner 40 Hz, 2× the white levels) besides the
  stated ADC noise; ``quantisation`` — no θ noise at all, only the encoder's quantisation of φ; ``noise3x`` — white
  ADC noise at 3× the stated level;
* encoder rigs (benchmarks.suite_independent_dc), balancing, diagnosed against the shipped configs:
  ``noise3x`` — the macstepien rig's θ estimate with 3× the config's noise; ``quantisation`` — the QUBE's encoders
  alone; ``unstated`` — white noise on the QUBE's θ encoder (half a count rms) that its config says is absent.

Cases marked ``held_out`` were not run while the data-driven noise floor was built (the others were).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from benchmarks import suite_independent as ind
from benchmarks import suite_independent_dc as dc
from furuta_rt.recording import Recording

PREFILTER = 9e-4  # rad per 2 ms tick at the Bessel input: 4e-3 rad per 0.1 ms in density (1.6e-9 rad² s)


@dataclass(frozen=True)
class NullCase:
    name: str
    simulator: str  # "thesis" (suite_independent) or "dc" (suite_independent_dc)
    noise: str  # prefilter | coloured | quantisation | noise3x | unstated
    seed: int
    held_out: bool = False

    @property
    def config(self) -> str:
        """The shipped rig config the case is diagnosed against."""
        return "thesis" if self.simulator == "thesis" else ("macstepien" if self.noise == "noise3x" else "qube_servo2")


CASES: list[NullCase] = [
    NullCase("thesis prefilter", "thesis", "prefilter", 101),
    NullCase("thesis coloured", "thesis", "coloured", 102),
    NullCase("thesis quantisation", "thesis", "quantisation", 103),
    NullCase("thesis noise3x", "thesis", "noise3x", 104),
    NullCase("dc macstepien noise3x", "dc", "noise3x", 51),
    NullCase("dc qube quantisation", "dc", "quantisation", 52),
    NullCase("dc qube unstated", "dc", "unstated", 53),
    NullCase("thesis prefilter b", "thesis", "prefilter", 111, held_out=True),
    NullCase("thesis coloured b", "thesis", "coloured", 112, held_out=True),
    NullCase("thesis noise3x b", "thesis", "noise3x", 114, held_out=True),
    NullCase("dc macstepien noise3x b", "dc", "noise3x", 61, held_out=True),
    NullCase("dc qube unstated b", "dc", "unstated", 63, held_out=True),
]


def simulate(case: NullCase, duration: float) -> Recording:
    """``duration`` s of the case (balancing, nothing concealed)."""
    if case.simulator == "thesis":
        base = ind.Case(case.name, seed=case.seed)
        kw = {"prefilter": {"prefilter": PREFILTER}, "coloured": {"coloured": 2.0}, "quantisation": {"noise": False},
              "noise3x": {"noise_scale": 3.0}}[case.noise]
        return ind.simulate(base, duration, **kw)
    shape = {"noise3x": dataclasses.replace(dc.MACSTEPIEN, theta_noise=3e-4),
             "quantisation": dataclasses.replace(dc.QUBE, theta_noise=0.0),
             "unstated": dataclasses.replace(dc.QUBE, theta_noise=0.5 * 2 * 3.141592653589793 / dc.QUBE.counts[0])
             }[case.noise]
    return dc.simulate(dc.DCCase(case.name, shape, "balance", seed=case.seed), duration)


def generate(case: NullCase, duration: float, cache: Path | None = None) -> Recording:
    """The case's recording (from ``cache`` when there: suite.cached)."""
    import hashlib

    from benchmarks.suite import cached

    key = hashlib.sha1(repr(("null", case, duration, 1)).encode()).hexdigest()[:16]
    return cached(key, cache, lambda: simulate(case, duration))
