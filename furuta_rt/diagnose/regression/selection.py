"""Which effects the data asks for: forward stepwise selection on held-out time blocks.

Per equation of eq. 4, starting from the nominal model, every candidate not yet in the model is added
in turn (its nonlinear parameter — delay, deadzone width, saturation limit — profiled on a grid, the
grid value chosen on the training blocks only), and the candidate that lowers the held-out (blocked
K-fold) squared error most is kept if

* the held-out error drops by at least ``min_gain`` (relative), and by more than the BIC penalty of
  its parameters on the effective number of samples,
* its main parameter is significant (|value| ≥ ``t_min`` jackknife standard errors, or ≥ ``t_strong`` when
  the held-out gain is large, ≥ ``strong_gain``: the fold-wise optima of a nonlinear parameter scatter
  more than its error), and
* the parameters are physically admissible (friction opposes motion, springs restore, ...).

A backward pass then drops any effect whose removal costs less than ``min_gain``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from furuta_rt.diagnose.regression.fitting import Blocks, Design, Fit, Stats, fit, fit_profiled, paired_t
from furuta_rt.diagnose.regression.library import ARM, CANDIDATES, Candidate, Context, InputPath, kink_supported


@dataclass(frozen=True)
class Spec:
    """A model of one equation: the effects it contains and the command path's nonlinear parameters."""

    equation: str
    effects: tuple[str, ...] = ()
    path: InputPath = field(default_factory=InputPath)
    d_inertia: float = 0.0  # arm inertia change ΔJ (kg m²)
    vs: float = 0.0  # Stribeck speed of arm_lugre (rad/s)
    base: InputPath = field(default_factory=InputPath)  # the nominal command path (the rig's own effects)

    def with_value(self, kind: str, value: float) -> Spec:
        if kind == "inertia":
            return replace(self, d_inertia=value)
        if kind == "vs":
            return replace(self, vs=value)
        return replace(self, path=replace(self.path, **{path_field(kind): value}))

    def with_effect(self, name: str) -> Spec:
        return replace(self, effects=(*self.effects, name))

    def without(self, name: str) -> Spec:
        """The model without ``name`` and without the effects that require it (arm_lugre's Stribeck peak sits on
        arm_coulomb's sliding level: without that level it has no meaning, and its refit goes negative)."""
        rest = self._drop(name)
        for dep in [e for e in rest.effects if CANDIDATES[e].requires == name]:
            rest = rest.without(dep)
        return rest

    def _drop(self, name: str) -> Spec:
        kind = CANDIDATES[name].nonlinear
        rest = replace(self, effects=tuple(e for e in self.effects if e != name))
        if kind is None:
            return rest
        return rest.with_value(kind, 0.0 if kind in ("inertia", "vs") else getattr(self.base, path_field(kind)))  # type: ignore[arg-type]


def path_field(kind: str) -> str:
    """The InputPath field a nonlinear parameter sets (command_latency moves the same delay as input_delay)."""
    return "delay" if kind == "latency" else kind


@dataclass
class Evaluation:
    spec: Spec
    fit: Fit
    params: dict[str, dict[str, float]]
    t_stat: dict[str, float]  # main parameter / its jackknife error
    se: dict[str, dict[str, float]] = field(default_factory=dict)

    @property
    def cv(self) -> float:
        return self.fit.cv_sse


@dataclass(frozen=True)
class Thresholds:
    min_gain: float = 0.003
    t_min: float = 4.0
    strong_gain: float = 0.05  # a held-out gain this large is evidence enough with t ≥ t_strong
    t_strong: float = 2.0
    n_blocks: int = 10


class EquationModel:
    """Builds and scores Specs of one equation on one recording."""

    def __init__(self, ctx: Context, equation: str, thresholds: Thresholds, row_filter: np.ndarray | None = None) -> None:
        self.ctx = ctx
        self.equation = equation
        self.th = thresholds
        mask = ctx.arm_rows if equation == ARM else ctx.pend_rows
        if row_filter is not None:
            mask = mask & row_filter
        self.blocks = Blocks.split(mask, thresholds.n_blocks)
        self.n_rows = len(self.blocks.rows)
        self.corr_len = ctx.states(equation).filt.sigma * 2.5 / ctx.prep.dt  # samples per independent residual
        self._step_evals: dict[int, dict[str, Evaluation]] = {}  # forward step → candidate → its evaluation
        self._trace: list[dict] = []

    def spec0(self) -> Spec:
        """The nominal model of this equation (with the rig's own command path)."""
        return Spec(self.equation, path=self.ctx.base_path, base=self.ctx.base_path)

    @property
    def candidates(self) -> list[Candidate]:
        """This equation's candidates (the command path's only when there is a command)."""
        commanded = self.ctx.prep.commanded
        return [
            c for c in CANDIDATES.values()
            if c.equation == self.equation and (commanded or not c.effect.on_command)
            and (c.searched or c.name in self.ctx.also_search)
        ]

    def target(self, spec: Spec) -> np.ndarray:
        return self.ctx.arm_residual(spec.path, spec.d_inertia) if self.equation == ARM else self.ctx.pend_residual

    def design(self, spec: Spec) -> tuple[np.ndarray, list[tuple[str, slice]]]:
        cols, owners, k = [], [], 0
        for name in spec.effects:
            X = CANDIDATES[name].columns(self.ctx, spec.path, spec.vs)
            if X.shape[1]:
                cols.append(X)
                owners.append((name, slice(k, k + X.shape[1])))
                k += X.shape[1]
        X = np.column_stack(cols) if cols else np.zeros((self.ctx.prep.n, 0))
        return X, owners

    def stats(self, spec: Spec) -> tuple[Stats, list[tuple[str, slice]]]:
        X, owners = self.design(spec)
        y = self.target(spec)
        if self.equation == ARM and spec.d_inertia:
            w = self.ctx.arm_weight(spec.d_inertia)
            y, X = y * w, X * np.asarray(w)[:, None]
        return Stats.of(y, X, self.blocks), owners

    def profile(self, spec: Spec, kind: str) -> Callable[[float], Stats]:
        """value → ``stats(spec.with_value(kind, value))[0]``, with what does not change along the profile taken once, on
        the equation's rows only: the design (its scales and blocks' Gram matrices) when no column moves with the command
        path or the Stribeck speed, and the arm's residual, ∂ID/∂J and M22 for an inertia (ID is linear in J). The same
        arithmetic, element by element, as ``stats``: the same numbers."""
        rows = self.blocks.rows
        if kind == "inertia" and self.equation == ARM:
            X, _ = self.design(spec)  # the columns do not depend on ΔJ; the residual is linear in it (arm_residual)
            Xr, y0 = X[rows], self.target(spec.with_value(kind, 0.0))[rows]
            dJ, m22 = self.ctx.arm_dJ[rows], self.ctx.arm_m22[rows]

            def inertia(value: float) -> Stats:
                if not value:
                    return Stats.of_rows(y0, Xr, self.blocks)
                w = m22 / (m22 + value)
                return Stats.of_rows((y0 + value * dJ) * w, Xr * w[:, None], self.blocks)

            return inertia
        if kind in ("inertia", "vs") or any(CANDIDATES[e].effect.varying for e in spec.effects):
            return lambda value: self.stats(spec.with_value(kind, value))[0]
        X, _ = self.design(spec)  # the same columns at every value of the command path's parameter
        w = self.ctx.arm_weight(spec.d_inertia) if self.equation == ARM and spec.d_inertia else None
        design = Design.of_rows(X[rows] if w is None else (X * np.asarray(w)[:, None])[rows], self.blocks)
        wr = None if w is None else np.asarray(w)[rows]

        def path_value(value: float) -> Stats:
            y = self.target(spec.with_value(kind, value))[rows]
            return design.stats(y if wr is None else y * wr, self.blocks)

        return path_value

    def _finish(self, spec: Spec, f: Fit, owners: list[tuple[str, slice]], nl_folds: np.ndarray | None = None,
                nl_name: str | None = None, nl_step: float = 0.0, nl_value: float = 0.0,
                edges: tuple[float, float, float] | None = None) -> Evaluation:
        gain = self.ctx.known_gain
        for name, sl in owners:
            if name == "input_gain":
                gain = self.ctx.known_gain * (1.0 + float(f.coef[sl][0]))
        params, tstat, se = {}, {}, {}
        for name in spec.effects:
            cand = CANDIDATES[name]
            sl = dict(owners).get(name)
            coef = f.coef[sl] if sl is not None else np.zeros(0)
            params[name] = cand.params(coef, spec.path, gain, self.ctx, spec.d_inertia)
            if sl is not None:
                err = f.se[sl]
                tstat[name] = abs(float(coef[0])) / max(float(err[0]), 1e-300)
                keys = ["Fs"] if name == "arm_lugre" else params[name]
                se[name] = {k: float(e) for k, e in zip(keys, err, strict=False)}
        if "arm_lugre" in params:  # the Stribeck peak on top of the Coulomb level (and viscous term) of the same fit
            params["arm_lugre"] = self.ctx.lugre_params(params, spec.vs)
        if nl_name is not None and nl_folds is not None:
            B = len(nl_folds)
            spread = float(np.sqrt((B - 1) / B * np.sum((nl_folds - nl_folds.mean()) ** 2)))
            err = max(spread, 0.5 * nl_step)
            # significance of the departure from nominal (ΔJ, delay, width); a limit is judged by CV alone
            kind = CANDIDATES[nl_name].nonlinear
            if kind == "vs":  # LuGre's size is its Stribeck peak (linear, judged above); vs only shapes it
                se[nl_name] = {**se.get(nl_name, {}), "vs": err}
            else:
                tstat[nl_name] = self._nonlinear_t(nl_name, nl_value, err, edges)
                se[nl_name] = {next(iter(params[nl_name])): err}
        return Evaluation(spec, f, params, tstat, se)

    def _nonlinear_t(self, name: str, value: float, err: float, edges: tuple[float, float, float] | None) -> float:
        """Significance of a nonlinear parameter's departure from the nominal model (ΔJ, delay, width; a saturation:
        how far below the largest command its limit sits). 0 — not identified — when the optimum sits on an edge of
        the range searched (``edges``: its ends and step) away from the nominal value (the data asks for more than
        the range, or for something else: a profile that runs away is no estimate, and the spread of fold optima
        pinned to one edge is not its error), and for a deadzone or saturation without commands on both sides of
        its kink (kink_supported)."""
        kind = CANDIDATES[name].nonlinear
        if kind in ("deadzone", "limit"):
            u = self.ctx.prep.u[self.blocks.rows]
            if not kink_supported(u, value):
                return 0.0
        if kind == "limit":
            null = float(np.max(np.abs(self.ctx.prep.u[self.blocks.rows])))
            if self.spec0().path.limit is not None:
                null = min(null, self.spec0().path.limit)
        else:
            null = 0.0 if kind == "inertia" else getattr(self.spec0().path, path_field(kind)) or 0.0  # type: ignore[arg-type]
        if edges is not None:
            lo, hi, step = edges
            if (value <= lo + step and abs(lo - null) > step) or (value >= hi - step and abs(hi - null) > step):
                return 0.0
        return abs(value - null) / max(err, 1e-300)

    def residual(self, spec: Spec, coef: np.ndarray | None = None) -> np.ndarray:
        """The (inertia-weighted) residual of ``spec`` with linear coefficients ``coef`` (none: the target)."""
        y = self.target(spec)
        if coef is not None and coef.size:
            X, _ = self.design(spec)
            y = y - X @ coef
        return y * self.ctx.arm_weight(spec.d_inertia) if self.equation == ARM else y

    @property
    def row_mask(self) -> np.ndarray:
        m = np.zeros(self.ctx.prep.n, dtype=bool)
        m[self.blocks.rows] = True
        return m

    def evaluate(self, spec: Spec) -> Evaluation:
        st, owners = self.stats(spec)
        return self._finish(spec, fit(st), owners)

    def grid(self, kind: str) -> np.ndarray:
        u = np.abs(self.ctx.prep.u[self.ctx.prep.valid])
        u = u[u > 0] if np.any(u > 0) else np.ones(1)  # the commands that act (a command 0 on most samples: the rest)
        if kind == "delay":
            return np.arange(0.0, 0.05 + 1e-12, 0.00025)
        if kind == "latency":  # a total shorter than the nominal one, down to one tick below 0 (acausal: a profile that
            # runs there is not a latency, and is rejected as implausible; a true latency of 0 is then an interior optimum)
            lag, top = self.ctx.prep.command_lag, self.ctx.base_path.delay
            return np.append(np.arange(-lag - self.ctx.prep.dt, top - 1e-4, 0.00025), top)
        if kind == "deadzone":
            return np.linspace(0.0, float(np.quantile(u, 0.8)), 41)
        if kind == "limit":
            return np.linspace(float(np.quantile(u, 0.6)), float(u.max()) * 1.001, 31)
        if kind == "vs":  # Stribeck speed, rad/s
            return np.geomspace(0.01, 1.0, 21)
        if kind == "inertia":  # J_true / J_nominal from 0.1 to 10 in 1 % steps (datasheet inertias can be off ×3 or more)
            J = self.ctx.base_inertia
            return J * (np.exp(np.arange(np.log(0.1), np.log(10.0), 0.01)) - 1.0)
        raise KeyError(kind)

    @staticmethod
    def nonlinear_value(spec: Spec, name: str) -> float | None:
        """The value of ``name``'s nonlinear parameter in ``spec`` (None for a linear effect)."""
        kind = CANDIDATES[name].nonlinear
        if kind is None:
            return None
        return {"inertia": spec.d_inertia, "vs": spec.vs}.get(kind, getattr(spec.path, path_field(kind), None))

    @staticmethod
    def can_add(spec: Spec, name: str) -> bool:
        """Whether ``name`` may join ``spec``: not in it yet, what it requires is, nothing it excludes is."""
        cand = CANDIDATES[name]
        need = cand.requires
        return (name not in spec.effects and (need is None or need in spec.effects)
                and not any(e in spec.effects for e in cand.excludes))

    def evaluate_with(self, spec: Spec, name: str) -> Evaluation:
        """``spec`` + candidate ``name``, its nonlinear parameter (if any) profiled on a grid."""
        cand = CANDIDATES[name]
        new = spec.with_effect(name)
        if cand.nonlinear is None:
            return self.evaluate(new)
        grid = self.grid(cand.nonlinear)
        f, value, folds = fit_profiled(self.profile(new, cand.nonlinear), grid)
        step = float(np.median(np.diff(grid))) if len(grid) > 1 else 0.0
        _, owners = self.design(new.with_value(cand.nonlinear, value))
        edges = (float(grid[0]), float(grid[-1]), step) if len(grid) > 1 else None
        return self._finish(new.with_value(cand.nonlinear, value), f, owners, folds, name, 0.1 * step, value, edges)

    def bic_penalty(self, k_added: int, sse: float) -> float:
        """ΔSSE a new parameter must buy on the effective sample count (BIC with n_eff = n / corr_len)."""
        n_eff = max(self.n_rows / self.corr_len, 10.0)
        return k_added * np.log(n_eff) * sse / n_eff

    def admissible(self, ev: Evaluation, name: str, gain: float = 0.0) -> bool:
        t = ev.t_stat.get(name, 0.0)
        significant = t >= self.th.t_min or (gain >= self.th.strong_gain and t >= self.th.t_strong)
        if name == "command_latency" and gain < self.th.strong_gain:
            # the whole command path's timing: a latency half a tick off already costs ~5 % of a commanded arm's residual;
            # smaller gains came from other misfits (2 % in a model with a gain standing in for an inertia change)
            return False
        return self.inside(ev, name) and significant

    def inside(self, ev: Evaluation, name: str) -> bool:
        """Physically admissible (Candidate.plausible), and a profiled parameter not at the far end of its grid: an optimum
        that runs to ×10 or ×0.1 the datasheet's arm inertia, to a deadzone as wide as most commands, to a limit that
        clips 40 % of them or to the longest delay searched is no estimate — the data asks for something the effect
        only mimics (a 10× inertia for a 6× torque per volt, a deadzone for a gain below 1)."""
        if not CANDIDATES[name].plausible(ev.params[name], self.ctx.rig, self.ctx.arm_travel):
            return False
        kind = CANDIDATES[name].nonlinear
        if kind not in FAR_END:
            return True
        grid = self.grid(kind)
        ends = [grid[i] for i in FAR_END[kind]]
        value = self.nonlinear_value(ev.spec, name)
        return value is None or not any(np.isclose(value, e, rtol=1e-9, atol=0.0) for e in ends)

    def select(self, allowed: set[str] | None = None) -> tuple[Evaluation, Evaluation, list[dict]]:
        """(nominal evaluation, selected evaluation, trace of the steps)."""
        nominal = self.evaluate(self.spec0())
        current = nominal
        trace: list[dict] = []
        if self.n_rows < 20 * self.th.n_blocks:
            return nominal, current, trace
        names = [c.name for c in self.candidates if allowed is None or c.name in allowed]
        self._trace = trace
        while True:
            best: tuple[float, Evaluation, str] | None = None
            for name in names:
                if not self.can_add(current.spec, name):
                    continue
                ev = self.evaluate_with(current.spec, name)
                self._step_evals.setdefault(len(current.spec.effects), {})[name] = ev
                gain = (current.cv - ev.cv) / current.cv
                k = max(1, ev.fit.coef.size - current.fit.coef.size)
                ok = (
                    gain >= self.th.min_gain
                    and current.cv - ev.cv > self.bic_penalty(k, ev.cv)
                    and self.admissible(ev, name, gain)
                )
                trace.append({"step": len(current.spec.effects), "candidate": name, "cv_gain": gain,
                              "t": ev.t_stat.get(name, 0.0), "params": ev.params[name], "accepted": False, "ok": ok,
                              "value": self.nonlinear_value(ev.spec, name)})
                if ok and (best is None or gain > best[0]):
                    best = (gain, ev, name)
            if not current.spec.effects:
                block = self.joint_first(current, names, trace, best[1] if best is not None else None)
                if block is not None:
                    current = block
                    continue
            if best is None:
                pair = self.best_pair(current, names, trace)
                if pair is None:
                    break
                current = pair
                continue
            current = best[1]
            for row in trace:
                if row["candidate"] == best[2] and row["step"] == len(current.spec.effects) - 1:
                    row["accepted"] = True
        joint = self.joint_step(current, names, trace)
        if joint is not None:
            current = joint
        # backward pass: every kept effect must still pay for itself (a pair's members given each other) and stay
        # physical once the others moved (an effect the rig does not have, refitted negative, is no effect)
        changed = True
        while changed and current.spec.effects:
            changed = False
            for name in current.spec.effects:
                reduced = self.evaluate(current.spec.without(name))
                if ((name not in self.ctx.known and not CANDIDATES[name].plausible(
                        current.params[name], self.ctx.rig, self.ctx.arm_travel))
                        or (reduced.cv - current.cv) / reduced.cv < self.th.min_gain):
                    current = reduced
                    changed = True
                    break
        return nominal, current, trace

    def rivals(self, name: str, spec: Spec) -> list[str]:
        """Candidates that scored within their uncertainty of ``name`` at the forward step that accepted it: admissible,
        and the held-out errors over the blocks not clearly worse (paired t < RIVAL_T or within RIVAL_GAIN relative),
        and able to take its place in ``spec``. stages.lookalikes.check_lookalikes tries them beside the library's fixed pairs."""
        for step, evals in sorted(self._step_evals.items()):
            won = evals.get(name)
            if won is None or not any(r["accepted"] and r["candidate"] == name and r["step"] == step for r in self._trace):
                continue
            out = []
            for other, ev in evals.items():
                if (other == name or not CANDIDATES[other].plausible(ev.params[other], self.ctx.rig, self.ctx.arm_travel)
                        or not self.can_add(spec.without(name), other)):
                    continue
                rel = (ev.cv - won.cv) / won.cv if won.cv else 0.0
                if rel < RIVAL_GAIN or paired_t(ev.fit.cv_block, won.fit.cv_block) < RIVAL_T:
                    out.append(other)
            return out
        return []

    def best_pair(self, current: Evaluation, names: list[str], trace: list[dict]) -> Evaluation | None:
        """Two effects that pay only together (when no single one is accepted): every admissible pair is screened with
        the nonlinear parameters at their single-candidate optima (one least-squares fit each), the best ones fitted
        with those parameters re-profiled given the other member; accepted by the rules of a single step applied to
        the pair (held-out gain ≥ 2·min_gain beyond the BIC penalty of both) and to each member given the other
        (significant, admissible, and its removal costs ≥ min_gain: the backward check)."""
        step = len(current.spec.effects)
        singles = {r["candidate"]: r for r in trace if r["step"] == step}
        pool = [n for n in names if self.can_add(current.spec, n) and n in singles]
        screened: list[tuple[float, str, str]] = []
        for i, a in enumerate(pool):
            for b in pool[i + 1 :]:
                spec = current.spec
                for n in (a, b):
                    spec = spec.with_effect(n) if self.can_add(spec, n) else None  # type: ignore[union-attr]
                    if spec is None:
                        break
                    kind = CANDIDATES[n].nonlinear
                    if kind is not None:
                        spec = spec.with_value(kind, singles[n]["value"])
                if spec is None:
                    continue
                cv = fit(self.stats(spec)[0]).cv_sse
                # what the pair adds beyond its better member alone (each must pay given the other)
                alone = max(singles[a]["cv_gain"], singles[b]["cv_gain"])
                screened.append(((current.cv - cv) / current.cv - max(alone, 0.0), a, b))
        screened.sort(reverse=True)
        for extra, a, b in screened[:PAIRS_REFINED]:
            if extra < 2 * self.th.min_gain:
                break
            ev = self.evaluate_with(current.spec, a)
            ev = self.evaluate_with(ev.spec, b)
            if CANDIDATES[a].nonlinear is not None:  # a re-profiled given b (one pass of coordinate descent)
                redo = self.evaluate_with(ev.spec.without(a), a)
                ev = Evaluation(redo.spec, redo.fit, redo.params, {**ev.t_stat, **redo.t_stat}, {**ev.se, **redo.se})
            gain = (current.cv - ev.cv) / current.cv
            k = max(2, ev.fit.coef.size - current.fit.coef.size)
            members_pay = all(
                self.admissible(ev, n, gain) and (self.evaluate(ev.spec.without(n)).cv - ev.cv) >= self.th.min_gain * ev.cv
                for n in (a, b)
            )
            ok = gain >= 2 * self.th.min_gain and current.cv - ev.cv > self.bic_penalty(k, ev.cv) and members_pay
            trace.append({"step": step, "candidate": f"{a}+{b}", "pair": [a, b], "cv_gain": gain,
                          "t": min(ev.t_stat.get(a, 0.0), ev.t_stat.get(b, 0.0)),
                          "params": {a: ev.params[a], b: ev.params[b]}, "accepted": ok, "ok": ok})
            if ok:
                return ev
        return None


    def _joint_members(self, current: Evaluation, names: list[str]) -> list[str]:
        """The JOINT members that may still join ``current`` (none off the commanded arm equation)."""
        if self.equation != ARM or not self.ctx.prep.commanded:
            return []
        return [n for n in JOINT if n in names and self.can_add(current.spec, n)]

    def _joint(self, current: Evaluation, added: list[str]) -> Evaluation:
        """``current`` with the JOINT members ``added`` fitted together (ΔJ started from its linear least-squares value,
        ID being linear in J, then profiled)."""
        spec = current.spec
        for n in added:
            spec = spec.with_effect(n)
        if "arm_inertia" not in added:
            return self.evaluate(spec)
        X, _ = self.design(spec)
        y = self.target(spec)
        f = fit(Stats.of(y, np.column_stack([X, -self.ctx.arm_dJ]), self.blocks))
        grid = self.grid("inertia")
        spec = spec.with_value("inertia", float(np.clip(f.coef[-1], grid[0], grid[-1])))
        return self.evaluate_with(spec.without("arm_inertia"), "arm_inertia")

    def _joint_row(self, current: Evaluation, ev: Evaluation, added: list[str], gain: float, ok: bool,
                   first: bool = False) -> dict:
        return {"step": len(current.spec.effects), "candidate": "+".join(added), "pair": added, "joint": True,
                "first": first, "cv_gain": gain, "t": min(ev.t_stat.get(n, 0.0) for n in added),
                "params": {n: ev.params[n] for n in added}, "accepted": ok, "ok": ok}

    def joint_first(self, current: Evaluation, names: list[str], trace: list[dict],
                    best: Evaluation | None) -> Evaluation | None:
        """The datasheet's arm parameters (JOINT) calibrated together before any other effect, when that explains far
        more than the best single effect: its held-out error at most (1 − JOINT_FIRST) of the best single's, beyond the
        BIC penalty of the extra parameters, every member admissible. A torque per volt and an inertia both off leave
        a residual that one effect alone can only mimic — an inertia ×10 for a gain ×3, a wide deadzone for a gain
        below 1 (on a command with dither or of constant amplitude a deadzone is a smooth gain reduction) — and the
        greedy steps built on that stand-in do not come back from it. The backward pass then drops the members that do
        not pay given the others."""
        added = self._joint_members(current, names)
        if len(added) < len(JOINT):
            return None
        ref = best if best is not None else current
        without_j = [n for n in added if n != "arm_inertia"]
        for members in (added, [*added, *OFFSET], without_j, [*without_j, *OFFSET]):  # the fewest parameters first
            members = [n for n in members if n in names and self.can_add(current.spec, n)]
            ev = self._joint(current, members)
            k = max(1, ev.fit.coef.size + ("arm_inertia" in members) - ref.fit.coef.size - (ref.spec.d_inertia != 0.0))
            gain = (current.cv - ev.cv) / current.cv if current.cv else 0.0
            ok = (ev.cv <= (1.0 - JOINT_FIRST) * ref.cv and ref.cv - ev.cv > self.bic_penalty(k, ev.cv)
                  and gain >= 2 * self.th.min_gain and all(self.inside(ev, n) for n in members))
            trace.append(self._joint_row(current, ev, members, gain, ok, first=True))
            if ok:
                return ev
        return None

    def joint_step(self, current: Evaluation, names: list[str], trace: list[dict]) -> Evaluation | None:
        """The arm's disputed nominal parameters — input gain, damping (arm_viscous), inertia — calibrated together on
        top of the selected effects (greedy steps can settle on one that stands in for the others, e.g. a 10× inertia
        for a 6× torque per volt): kept when the held-out error drops by ≥ 2·min_gain; the backward pass then drops
        the members that do not pay given the others."""
        added = self._joint_members(current, names)
        if not added:
            return None
        ev = self._joint(current, added)
        gain = (current.cv - ev.cv) / current.cv if current.cv else 0.0
        ok = gain >= 2 * self.th.min_gain and all(self.inside(ev, n) for n in added)
        trace.append(self._joint_row(current, ev, added, gain, ok))
        return ev if ok else None


FAR_END = {"inertia": (0, -1), "deadzone": (-1,), "limit": (0,), "delay": (-1,)}  # grid ends that are no estimate
RIVAL_T, RIVAL_GAIN = 3.0, 0.01  # as stages.findings.Options.ambiguity_t / ambiguity_gain
JOINT = ("input_gain", "arm_viscous", "arm_inertia")  # the arm parameters a datasheet most often gets wrong
PAIRS_REFINED = 3  # the best-screened pairs fitted in full (nonlinear parameters re-profiled)
OFFSET = ("arm_bias",)  # tried with JOINT when that alone does not go first: a constant torque (a DAC/amplifier offset, a
# cable's pull) is part of a motor's linear calibration; left out, a loop that holds it makes it read as a gain
JOINT_FIRST = 0.5  # the share of the best single effect's held-out error the joint calibration must remove to go first
