"""The diagnosis as text, as a report directory (report.html, its figures, summary.md, diagnosis.json).

Figures (matplotlib Agg canvases, no pyplot state):
  residuals.png  the inverse-dynamics residual of each equation before (nominal) and after (augmented)
  where.png      where the mismatch sits: the nominal residual against the signal it follows most, and per
                 operating region
  prediction.png held-out prediction windows: data, nominal and augmented simulations
  sticks.png     stick windows (when they found something): the measured arm, the arm simulated without and with
                 the breakaway torque / delay they found, and the command against Fc and Fs
  peaks.png      command-peak windows (when they found a limit): likewise
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from furuta_rt.diagnose.engine import Diagnosis
from furuta_rt.diagnose.judgement.locate import features
from furuta_rt.diagnose.judgement.verify import quiet, simulate_window
from furuta_rt.diagnose.report.page import MARKER, error_change, html_page, t_stat
from furuta_rt.diagnose.stages.decay import DecayResult
from furuta_rt.diagnose.stages.stickslip import WindowStage, simulate_arm
from furuta_rt.errors import UserError
from furuta_rt.model.effects import Effects
from furuta_rt.model.rig import RigModel

DPI = 150  # figures are 7–10 in wide: 1050–1500 px
NOT_ASSESSED_ROWS = 50  # an equation with fewer usable rows is shown as not assessed, not as an empty axis
UNITS = {  # the signals a residual is plotted against (locate.features), with units
    "sgn(φ̇)": "sgn(φ̇) (−1, 0, +1)", "φ̇": "φ̇ (rad/s)", "φ": "φ (rad)", "u": "u, command torque (N m)",
    "u̇": "u̇, command torque rate (N m/s)", "φ̈": "φ̈ (rad/s²)", "θ": "θ (rad)", "θ̇": "θ̇ (rad/s)",
    "sgn(θ̇)": "sgn(θ̇) (−1, 0, +1)", "1": "t (s)",
}


def _figure(rows: int, cols: int, size: tuple[float, float]) -> tuple[Figure, np.ndarray]:
    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    return fig, np.atleast_1d(fig.subplots(rows, cols, squeeze=False))


def fmt_params(params: dict[str, float], se: dict[str, float] | None = None) -> str:
    se = se or {}
    return ", ".join(f"{k} = {v:.4g}" + (f" ± {se[k]:.2g}" if k in se and np.isfinite(se[k]) else "") for k, v in params.items())


def text(d: Diagnosis) -> list[str]:
    """The report as lines of plain text."""
    lines = [d.summary, f"rig {d.rig}; diagnosed in {d.seconds:.1f} s"]
    if d.effects:
        lines.append("effects found (held-out error reduction, significance):")
        for e in d.effects:
            alone = "" if e.pinned or not e.combinations else " alone"
            how = (f"{e.equation} equation, {error_change(e.cv_gain)}, t = {t_stat(e.t)}{alone}" if e.source == "inverse dynamics"
                   else f"{e.equation} equation, from the {e.source}" + (
                       f": {error_change(e.cv_gain)}, t = {t_stat(e.t)}" if e.source.endswith("windows") else ""))
            lines.append(f"  {e.name}: {fmt_params(e.params, e.se)}   [{how}]")
            if not e.pinned:
                lines.append("    not pinned alone by this recording; " + (
                    "pinned: " + "; ".join(f"{c['name']} = {c['value']:.4g} ± {c['se']:.2g} {c['unit']} "
                                           f"({' with '.join(c['members'])})" for c in e.combinations)
                    if e.combinations else "nor any combination of it (its relative error in the joint fit of "
                    "input gain, arm inertia and damping is ≥ 10 %: see identification)"))
    else:
        lines.append("no library effect found (whether the nominal model explains the recording: the verdicts above)")
    for a in d.ambiguities:
        alt = a["alternative"]
        lines.append(f"ambiguous: {a['effects'][0]} or {alt['name']} ({fmt_params(alt['params'])}): {a['reason']}; "
                     f"to separate them: {a['experiment']}")
    for a in d.lookalikes:
        head = f"{a['effects'][0]} rather than {a['effects'][1]}"
        reason = a["reason"].removeprefix(head + ": ")  # the κ test's reason already starts with it
        lines.append(f"told apart: {head}: {reason}")
    lines.append(f"located: {d.located}")
    f = d.fit
    lines.append(f"fit: {f['verdict']} ({f['metric']}; {f['windows']} windows of {f['horizon_s']:.2f} s, paired t = "
                 f"{f['paired_t']:.1f} (of the logarithms {f.get('paired_t_log', float('nan')):.1f}), diverged "
                 f"{f['nominal_diverged']} → {f['augmented_diverged']}): "
                 f"nominal {f['nominal']:.4f} (θ {f['nominal_theta']:.4f}, φ {f['nominal_phi']:.4f}) → augmented "
                 f"{f['augmented']:.4f} (θ {f['augmented_theta']:.4f}, φ {f['augmented_phi']:.4f})")
    for e in d.not_predictive:
        lines.append(f"not predictive (not reported as found): {e['name']} ({fmt_params(e['params'])}): {e['reason']}")
    if d.closed_loop:
        lines.append("closed-loop re-simulation (std θ, std φ, std u, φ limit cycle amplitude / period):")
        for k in ("data", "nominal", "augmented"):
            s = d.closed_loop.get(k)
            if s:
                lc = (f"{s['lc_phi_amplitude']:.3g} rad / {s['lc_phi_period']:.2f} s" if s["lc_phi_amplitude"] is not None
                      else "none")
                lines.append(f"  {k:9s} {s['std_theta']:.4g} rad, {s['std_phi']:.4g} rad, {s['std_u']:.4g}, {lc}")
    lines += [f"note: {n}" for n in d.notes]
    return lines


def figures(d: Diagnosis, out: Path, prefix: str = "") -> list[Path]:
    """Write the report's figures into ``out``; returns their paths."""
    out.mkdir(parents=True, exist_ok=True)
    ctx = d.context
    t = ctx.prep.t - ctx.prep.t[0]
    paths = []
    # residuals before / after
    fig, ax = _figure(2, 1, (9, 5.5))
    for i, (eq, r) in enumerate(d.equations.items()):
        em = d.models[eq]
        rows = em.row_mask
        if rows.sum() < NOT_ASSESSED_ROWS:
            _not_assessed(ax[i, 0], eq, int(rows.sum()))
            continue
        y0 = em.residual(r.nominal.spec)
        y1 = em.residual(r.selected.spec, r.selected.fit.coef)
        a = ax[i, 0]
        same = np.allclose(y0[rows], y1[rows], rtol=0.0, atol=1e-12 * (1.0 + float(np.abs(y0[rows]).max())))
        a.plot(t[rows], y0[rows], ".", ms=1, color="C3",
               label="nominal (= augmented: no effect found here)" if same else "nominal")
        if not same:  # an identical series drawn over the first would be listed in the legend but invisible
            a.plot(t[rows], y1[rows], ".", ms=1, color="C0", label="augmented: " + ", ".join(r.selected.spec.effects))
        for k, (lo, hi) in enumerate(r.location.times):
            a.axvspan(lo - ctx.prep.t[0], hi - ctx.prep.t[0], color="C1", alpha=0.3, lw=0,
                      label="where it is largest" if k == 0 else None)
        a.set_ylabel(f"{eq} residual (N m)")
        a.set_xlabel("t (s)")
        a.set_title(f"{eq} equation: inverse-dynamics residual, nominal and augmented"
                    + ("; orange bands: where it is largest" if r.location.times else ""), fontsize=9)
        a.legend(loc="upper right", fontsize=7, markerscale=6)
    paths.append(_save(fig, out / f"{prefix}residuals.png"))
    # where: nominal residual against the signal it follows most (one row per equation, so the titles fit)
    fig, ax = _figure(2, 1, (9, 6.5))
    for i, (eq, r) in enumerate(d.equations.items()):
        a = ax[i, 0]
        rows = d.models[eq].row_mask
        if rows.sum() < NOT_ASSESSED_ROWS or not r.location.correlations:
            _not_assessed(a, eq, int(rows.sum()))
            continue
        corr = {k: v for k, v in r.location.correlations.items() if k != "1"}
        key = max(corr, key=lambda k: abs(corr[k])) if corr else "1"
        y0 = d.models[eq].residual(r.nominal.spec)[rows]
        if abs(r.location.correlations.get("1", 0.0)) > 0.5:  # a constant bias: show it against time and zero
            key = "1"
        x = t[rows] if key == "1" else features(ctx, eq)[key][rows]
        a.plot(x, y0, ".", ms=1, alpha=0.3, color="C3")
        a.axhline(0.0, color="k", lw=0.8)
        a.set_xlabel(UNITS.get(key, key))
        a.set_ylabel(f"{eq} residual (N m)")
        what = "a constant bias" if key == "1" else f"follows {key} (r = {corr.get(key, 0):+.2f})"
        a.set_title(f"{eq} equation: nominal residual {100 * r.location.relative_rms:.1f} % of its torque scale; {what}",
                    fontsize=9)
        regions = "\n".join(f"{k}: rms ×{v:.1f} of elsewhere" for k, v in r.location.regions.items())
        if regions:  # beside the axes, not over the points
            a.text(1.02, 1.0, regions, transform=a.transAxes, va="top", ha="left", fontsize=7,
                   bbox={"facecolor": "white", "edgecolor": "0.8"})
    paths.append(_save(fig, out / f"{prefix}where.png"))
    # held-out prediction windows
    pred = d.prediction
    starts = pred.get("starts", [])
    if starts:
        chosen = starts[:: max(1, len(starts) // 4)][:4]
        fig, ax = _figure(2, len(chosen), (10, 5.5))  # one column per window (windows are short and far apart)
        rig = ctx.rig
        models = (RigModel.from_config(quiet(rig)), RigModel.from_config(quiet(rig), pred["augmented"]))
        h = pred["horizon"]
        for j, k in enumerate(chosen):
            span = slice(k + 1, k + 1 + h)
            tt = t[span]
            ax[0, j].plot(tt, ctx.prep.theta_f[span], "k", lw=1.2, label="data")
            ax[1, j].plot(tt, ctx.prep.phi[span], "k", lw=1.2, label="data")
            for model, style, label in zip(models, ("C3--", "C0"), ("nominal", "augmented"), strict=True):
                th, ph = simulate_window(model, ctx.prep, ctx.fine, k, h, pred["substep_hz"])
                ax[0, j].plot(tt, th, style, lw=1, label=label)
                ax[1, j].plot(tt, ph, style, lw=1, label=label)
            for i in (0, 1):
                ax[i, j].set_xlabel("t (s)", fontsize=8)
                ax[i, j].tick_params(labelsize=7)
        ax[0, 0].set_ylabel("θ_f, pendulum (rad)", fontsize=8)
        ax[1, 0].set_ylabel("φ, arm (rad)", fontsize=8)
        ax[0, 0].legend(fontsize=7)
        fig.suptitle(f"held-out prediction, {len(chosen)} of {len(starts)} windows of {h * ctx.prep.dt:.2f} s; NRMSE over all: "
                     f"nominal {d.fit['nominal']:.3f}, augmented {d.fit['augmented']:.3f}", fontsize=9)
        paths.append(_save(fig, out / f"{prefix}prediction.png"))
    if d.decay_result is not None:
        paths.append(decay_figure(d.decay_result, out / f"{prefix}decay.png"))
    for stage, name in ((d.stick, "sticks"), (d.peak, "peaks")):
        if stage is not None and stage.added:
            paths.append(window_figure(d, stage, out / f"{prefix}{name}.png"))
    return paths


def window_figure(d: Diagnosis, stage: WindowStage, path: Path, count: int = 4) -> Path:
    """Windows of a window stage (sticks or command peaks): the measured arm angle, the arm simulated without the
    stage's effects and with them (pendulum teacher-forced), and the command."""
    ctx = d.context
    prep = ctx.prep
    found = {e.name: e.params for e in d.effects}
    without = {k: v for k, v in found.items() if k not in stage.added}
    without |= {k: v for k, v in ctx.known.items() if k in stage.replaces and k not in without}
    rig = quiet(ctx.rig)
    models = (RigModel.from_config(rig, effects_of_dict(without)), RigModel.from_config(rig, effects_of_dict(found)))
    wins = stage.windows[:: max(1, len(stage.windows) // count)][:count]
    fig, ax = _figure(2, len(wins), (max(7.0, 2.6 * len(wins)), 4.8))
    t0 = prep.t[0]
    for i, w in enumerate(wins):
        span = slice(w.start + 1, w.start + 1 + w.horizon)
        tt = prep.t[span] - t0
        a = ax[0, i]
        a.step(tt, 1e3 * prep.phi[span], "k", where="post", lw=1, label="data (encoder)")
        labels = ("without " + ", ".join(stage.added), "with " + ", ".join(stage.added))
        for model, style, label in zip(models, ("C3--", "C0"), labels, strict=True):
            a.plot(tt, 1e3 * simulate_arm(model, prep, ctx.fine, w), style, lw=1, label=label)
        a.set_xlabel("t (s)")
        b = ax[1, i]
        b.step(tt, prep.u[w.start : w.start + w.horizon], "k", where="post", lw=0.8)
        for params in stage.added.values():
            level = params.get("Fs", params.get("limit"))
            if level is not None:
                for sgn in (1, -1):
                    b.axhline(sgn * level, color="C0", lw=0.8, ls=":")
        if "arm_coulomb" in found:
            for sgn in (1, -1):
                b.axhline(sgn * found["arm_coulomb"]["Fc"], color="C3", lw=0.8, ls=":")
        b.set_xlabel("t (s)")
    ax[0, 0].set_ylabel("φ (mrad)")
    ax[1, 0].set_ylabel("command u (N m)")
    ax[0, 0].legend(fontsize=6)
    fig.suptitle(f"{len(stage.windows)} windows; dotted: breakaway / limit (blue), sliding level Fc (red)", fontsize=8)
    return _save(fig, path)


def effects_of_dict(params: dict[str, dict[str, float]]) -> Effects:
    return Effects.model_validate(params)


def decay_figure(r: DecayResult, path: Path) -> Path:
    """Free decay: swing amplitude over time, and the energy lost per cycle against its amplitude with the
    viscous, Coulomb and combined fits."""
    fig, ax = _figure(1, 2, (9, 3.4))
    a = ax[0, 0]
    a.semilogy(r.peaks_t, r.peaks, ".", ms=3, color="k")
    a.set_xlabel("t (s)")
    a.set_ylabel("|θ − π| at turning points (rad)")
    a.set_title("amplitude (exponential = straight line here)", fontsize=8)
    a = ax[0, 1]
    a.loglog(r.amplitude, r.loss, "ko", ms=3, label="data")
    for name, style in (("viscous", "C0--"), ("coulomb", "C3:"), ("both", "C2-")):
        f = r.fits[name]
        label = {"viscous": f"viscous bp = {f.bp:.3g}", "coulomb": f"Coulomb Fc = {f.Fc:.3g}",
                 "both": f"both: bp = {f.bp:.3g}, Fc = {f.Fc:.3g}"}[name]
        a.loglog(r.amplitude, r.predicted_loss(name), style, label=f"{label} (LOO {100 * f.loo_rms:.0f} %)")
    a.set_xlabel("amplitude at the cycle's start (rad)")
    a.set_ylabel("energy lost per cycle (J)")
    a.legend(fontsize=7)
    return _save(fig, path)


OUTPUTS = ("report.html", "summary.md", "diagnosis.json", "residuals.png", "where.png", "prediction.png", "decay.png",
           "sticks.png", "peaks.png")  # everything write_report may write (and replace, in a directory it made)


def check_directory(out: Path) -> None:
    """Refuse a path that is a file, or a directory that holds anything but an earlier report (a user's files are
    never overwritten)."""
    if out.exists() and not out.is_dir():
        raise UserError(f"--report {out}: is a file; give a directory (it is created if missing)")
    if not out.exists():
        return
    present = {p.name for p in out.iterdir()}
    page = out / "report.html"
    ours = page.is_file() and MARKER in page.read_text(errors="replace")[:2000]
    foreign = sorted(present - set(OUTPUTS)) if ours else sorted(present)
    if foreign:
        raise UserError(f"--report {out}: the directory holds files that are not a furuta-rt report ({', '.join(foreign[:3])}"
                        f"{', …' if len(foreign) > 3 else ''}); give a new or empty directory")


def _own_directory(out: Path) -> None:
    """``out`` checked (check_directory), and an earlier report's outputs removed (no stale figure beside the page)."""
    check_directory(out)
    if out.exists():
        for p in out.iterdir():
            p.unlink()


def write_report(d: Diagnosis, out: Path) -> list[Path]:
    """report.html (the page a person reads), its figures, summary.md (text) and diagnosis.json in ``out``."""
    _own_directory(out)
    paths = figures(d, out)
    md = ["# furuta-rt diagnose", "", *[f"    {line}" for line in text(d)], ""]
    md += [f"![{p.stem}]({p.name})" for p in paths]
    (out / "summary.md").write_text("\n".join(md) + "\n")
    data = d.to_json()
    (out / "diagnosis.json").write_text(json.dumps(data, indent=1, default=float))
    page = out / "report.html"
    page.write_text(html_page(data, [p.name for p in paths], text(d)))
    return [*paths, page, out / "summary.md", out / "diagnosis.json"]


# ------------------------------------------------------------------------------ helpers
def _not_assessed(a, eq: str, rows: int) -> None:
    """A panel that says why an equation is not shown (instead of an empty axis)."""
    a.set_axis_off()
    a.text(0.5, 0.5, f"{eq} equation not assessed: {rows} usable samples (it needs the joint to move; see the notes)",
           transform=a.transAxes, ha="center", va="center", fontsize=10, wrap=True)


def _save(fig: Figure, path: Path) -> Path:
    fig.savefig(path, dpi=DPI)
    return path
