"""report.html: the diagnosis as one page a person reads, from its JSON (Diagnosis.to_json) and the figures beside it.

Summary verdict first; then per equation of eq. 4 its verdict, the residual before/after against the noise floor,
where the mismatch sits, what was found (with standard errors), its look-alikes with the experiment that would tell
them apart, and what stays unexplained; then the held-out prediction, the figures, the identification and the notes.
Keys that a diagnosis does not carry are left out, so the page renders any version of the JSON. All text is
escaped; images are linked relatively (the directory is self-contained).
"""

from __future__ import annotations

from html import escape
from typing import Any

MARKER = '<meta name="generator" content="furuta-rt diagnose">'  # tells a report directory from a user's
CSS = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em; color: #222; line-height: 1.45; }
h1 { font-size: 1.5em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: .2em; margin-top: 1.6em; }
.summary { font-size: 1.2em; background: #f3f6fa; border-left: 5px solid #3a6ea5; padding: .7em 1em; }
.verdict { font-weight: bold; padding: .1em .5em; border-radius: .3em; background: #eee; }
.consistent, .explained, .improved { background: #d9f2d9; } .partly_explained, .unchanged { background: #fff1c2; }
.unexplained, .worse, .diverges { background: #f9d0d0; } .not_assessed { background: #e4e4e4; }
table { border-collapse: collapse; margin: .5em 0; } td, th { border: 1px solid #ccc; padding: .25em .6em; text-align: left; }
img { max-width: 100%; height: auto; border: 1px solid #ddd; margin: .5em 0; }
.muted { color: #666; font-size: .9em; }
pre { background: #f6f6f6; padding: .8em; font-size: .85em; white-space: pre-wrap; overflow-wrap: anywhere; }
"""


def _e(x: object) -> str:
    return escape(str(x), quote=True)


def _num(x: object, digits: int = 4) -> str:
    return f"{x:.{digits}g}" if isinstance(x, int | float) and not isinstance(x, bool) else "—" if x is None else _e(x)


def _pct(x: object) -> str:
    return f"{100 * x:.1f} %" if isinstance(x, int | float) and not isinstance(x, bool) else "—"


def error_change(cv_gain: object) -> str:
    """A held-out error reduction (``cv_gain``, a fraction: 0.3 = the error fell by 30 %) as the change of the error,
    signed as the text report signs it: "−30.0 %" for a fall, "+5.0 %" for a rise."""
    if not isinstance(cv_gain, int | float) or isinstance(cv_gain, bool):
        return "—"
    change = -100 * cv_gain
    return f"{'−' if change < 0 else '+'}{abs(change):.1f} %"


def t_stat(t: object) -> str:
    """A significance t as the text report prints it: a whole number (not 1e+04), two digits below 10."""
    if not isinstance(t, int | float) or isinstance(t, bool):
        return "—"
    return f"{t:.0f}" if abs(t) >= 10 else f"{t:.2g}"


def _combined(e: dict) -> str:
    """The note on an effect the recording does not pin alone: the combinations of it the data pins (stages.findings.Found)."""
    if e.get("pinned", True):
        return ""
    combos = e.get("pinned_combinations") or []
    pinned = "; ".join(f"{_e(c['name'])} = {_num(c.get('value'), 4)} ± {_num(c.get('se'), 2)} {_e(c.get('unit', ''))}"
                       for c in combos)
    return "<br><i>not pinned alone by this recording" + (f"; pinned: {pinned}" if pinned else "") + "</i>"


def _params(params: dict[str, Any], se: dict[str, Any] | None = None) -> str:
    se = se or {}
    out = []
    for k, v in params.items():
        err = se.get(k)
        out.append(f"{_e(k)} = {_num(v)}" + (f" ± {_num(err, 2)}" if isinstance(err, int | float) else ""))
    return ", ".join(out) or "—"


def _value(c: dict[str, Any]) -> str:
    v = c.get("value")
    if isinstance(v, str):  # already worded with its uncertainty
        return _e(v)
    return f"{_num(v)} ± {_num(c.get('se'), 2)}"


def _removes(c: dict[str, Any]) -> str:
    r = c.get("removes")
    if isinstance(r, dict):
        parts = ", ".join(f"{_e(k)} {_pct(v)}" for k, v in r.items())
        total = c.get("removes_total")
        return parts + (f" (together {_pct(total)})" if isinstance(total, int | float) else "")
    return _pct(r)


def _table(head: list[str] | None, rows: list[list[str]]) -> str:
    """A table of already-escaped cells (``head`` None: no header row)."""
    h = "<tr>" + "".join(f"<th>{c}</th>" for c in head) + "</tr>" if head else ""
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table>{h}{body}</table>"


def _verdict(v: object) -> str:
    return f'<span class="verdict {_e(v)}">{_e(str(v).replace("_", " "))}</span>' if v else ""


def _equation(name: str, eq: dict[str, Any], data: dict[str, Any]) -> str:
    out = [f"<h3>{_e(name)} equation {_verdict(eq.get('verdict'))}</h3>"]
    if eq.get("reason"):
        out.append(f"<p>{_e(eq['reason'])}</p>")
    nominal = eq.get("residual_nominal", eq.get("relative_residual"))
    rows = [["residual, nominal model", _pct(nominal)]]
    if "residual_augmented" in eq:
        rows.append(["residual, with the effects found", _pct(eq["residual_augmented"])])
    if "noise_floor" in eq:
        rows.append(["noise floor (what the sensors alone explain)", _pct(eq["noise_floor"])])
    rows.append(["held-out error change with the effects found", error_change(eq.get("cv_gain"))])
    rows.append(["usable samples", _num(eq.get("rows"))])
    out.append("<p class=muted>residuals: rms relative to the equation's torque scale</p>" + _table(None, rows))
    corr = {k: v for k, v in (eq.get("correlations") or {}).items() if k != "1" and isinstance(v, int | float)}
    top = sorted(corr.items(), key=lambda kv: -abs(kv[1]))[:3]
    where = []
    if top:
        where.append("the nominal residual follows " + ", ".join(f"{_e(k)} (r = {v:+.2f})" for k, v in top))
    regions = eq.get("regions") or {}
    if regions:
        where.append("rms by region against elsewhere: " + ", ".join(f"{_e(k)} ×{_num(v, 2)}" for k, v in regions.items()))
    if where:
        out.append("<p><b>Where:</b> " + "; ".join(where) + "</p>")
    found = [e for e in data.get("evidence") or [] if e.get("equation") == name]
    params = {e["name"]: e.get("params", {}) for e in data.get("effects") or []}
    if found:
        out.append("<p><b>Found:</b></p>" + _table(
            ["effect", "parameters ± standard error", "from", "held-out error change", "t"],
            [[_e(e["name"]), _params(params.get(e["name"], {}), e.get("se")) + _combined(e), _e(e.get("source", "")),
              error_change(e.get("cv_gain")), t_stat(e.get("t"))] for e in found]))
    else:
        out.append("<p><b>Found:</b> no library effect in this equation.</p>")
    names = {e["name"] for e in found}
    pairs = [a for a in (data.get("ambiguities") or []) + (data.get("lookalikes") or []) if names & set(a.get("effects", []))]
    if pairs:
        items = []
        for a in pairs:
            kind = "ambiguous" if "alternative" in a else "told apart"
            text = f"<b>{kind}</b>: {_e(' / '.join(a.get('effects', [])))} — {_e(a.get('reason', ''))}"
            if a.get("experiment"):
                text += f"<br><i>experiment that separates them:</i> {_e(a['experiment'])}"
            items.append(f"<li>{text}</li>")
        out.append("<p><b>Look-alikes:</b></p><ul>" + "".join(items) + "</ul>")
    un = eq.get("unexplained")
    if isinstance(un, dict):
        text = [f"<p><b>Unexplained:</b> {_pct(un.get('share'))} of the torque scale is left"
                + (f" (the effects found removed {_pct(un['removed_by_effects'])} of the nominal residual)"
                   if isinstance(un.get("removed_by_effects"), int | float) else "") + "."]
        text += [f"<br>{_e(w)}" for w in un.get("where") or []]
        sig = un.get("signature") or {}
        if isinstance(sig.get("peak_hz"), int | float):
            band = sig.get("band_hz") or []
            text.append(f"<br>its spectrum peaks at {sig['peak_hz']:.2g} Hz"
                        + (f" (band {band[0]:.2g}–{band[1]:.2g} Hz)" if len(band) == 2 else ""))
        text.append("</p>")
        causes = un.get("possible_causes") or []
        if causes:
            text.append(_table(["possible cause (outside the library)", "value", "removes (of what is left)"],
                               [[_e(c.get("cause", "")), _value(c), _removes(c)] for c in causes]))
        out.append("".join(text))
    return "\n".join(out)


def _identified(params: dict[str, Any]) -> list[list[str]]:
    """One row per quantity: a parameter the effects found report is in "Found" (the same value), and two names
    the fit gives the same value and error (the arm's viscous friction and its damping without back-EMF) share a row."""
    rows: dict[tuple[str, str], list[str]] = {}
    for k, v in params.items():
        if not isinstance(v, dict) or v.get("selected"):
            continue
        cells = (f"{_num(v.get('value'))} ± {_num(v.get('se'), 2)}", "yes" if v.get("pinned") else "no")
        if cells in rows:
            rows[cells][0] += f" = {_e(k)}"
        else:
            rows[cells] = [_e(k), *cells]
    return list(rows.values())


def html_page(data: dict[str, Any], images: list[str], lines: list[str]) -> str:
    """The page (``images``: figure file names beside it; ``lines``: the text report, shown in full at the end)."""
    summary = data.get("summary") or data.get("located") or ""
    body = [f"<h1>furuta-rt diagnose — rig {_e(data.get('rig', '?'))}</h1>", f'<p class="summary">{_e(summary)}</p>']
    eqs = data.get("equations") or {}
    if eqs:
        body.append("<h2>Per equation of eq. 4</h2>")
        body += [_equation(name, eq, data) for name, eq in eqs.items()]
    if data.get("not_predictive"):
        body.append("<h2>Lowered the residual but not the held-out prediction (not reported as found)</h2>" + _table(
            ["effect", "equation", "parameters", "why"],
            [[_e(e.get("name", "")), _e(e.get("equation", "")), _params(e.get("params") or {}), _e(e.get("reason", ""))]
             for e in data["not_predictive"]]))
    fit = data.get("fit") or {}
    details = data.get("fit_details") or {}
    if fit:
        body.append(f"<h2>Held-out prediction {_verdict(fit.get('verdict'))}</h2>")
        times = fit.get("window_times_s") or []
        span = (f"at t = {_num(min(times), 3)}–{_num(max(times), 3)} s" if times else
                f"from t = {_num(details.get('held_out_from_s'), 3)} s")
        windows = (f"{_num(fit.get('windows', details.get('windows')))} windows of "
                   f"{_num(fit.get('horizon_s', details.get('horizon_s')), 3)} s {span}")
        for key, what in (("nominal_diverged", "nominal diverged in"), ("augmented_diverged", "augmented diverged in")):
            if fit.get(key):
                windows += f"; {what} {_num(fit[key])}"
        if isinstance(fit.get("paired_t"), int | float):
            windows += f"; paired t = {fit['paired_t']:.1f}"
        body.append(f"<p>{_e(fit.get('metric', ''))}: nominal model {_num(fit.get('nominal'))}, with the effects found "
                    f"{_num(fit.get('augmented'))} ({windows}).</p>")
    if "prediction.png" in images:
        body.append('<img src="prediction.png" alt="held-out prediction windows: data, nominal and augmented models">')
    body.append("<h2>Residuals before and after, and where they sit</h2>")
    for name, alt in (("residuals.png", "inverse-dynamics residual of each equation, nominal and augmented"),
                      ("where.png", "nominal residual against the signal it follows most")):
        if name in images:
            body.append(f'<img src="{_e(name)}" alt="{_e(alt)}">')
    others = [n for n in images if n not in ("prediction.png", "residuals.png", "where.png")]
    if others:
        body.append("<h2>Window stages and free decay</h2>" + "".join(f'<img src="{_e(n)}" alt="{_e(n)}">' for n in others))
    ident = data.get("identification")
    if isinstance(ident, dict):
        body.append("<h2>Identification</h2>")
        if ident.get("unphysical"):  # an impossible joint fit is no finding: its values are not shown as such
            body.append(f"<p><b>Not identified:</b> {_e(ident['unphysical'])}.</p>")
        else:
            rows = _identified(ident.get("parameters") or {})
            if rows:
                body.append(_table(["parameter", "value ± se", "pinned"], rows))
        combos = ident.get("combinations") or {}
        if combos:
            body.append(_table(["combination", "value ± se", "unit"], [
                [_e(k), f"{_num(v.get('value'))} ± {_num(v.get('se'), 2)}", _e(v.get("unit", ""))] for k, v in combos.items()]))
    if data.get("notes"):
        body.append("<h2>Notes</h2><ul>" + "".join(f"<li>{_e(n)}</li>" for n in data["notes"]) + "</ul>")
    body.append("<h2>Text report</h2><pre>" + _e("\n".join(lines)) + "</pre>")
    body.append('<p class="muted">Files: <a href="diagnosis.json">diagnosis.json</a> (everything above, machine-readable), '
                '<a href="summary.md">summary.md</a>.</p>')
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            + MARKER +
            f"<title>furuta-rt diagnose — {_e(data.get('rig', ''))}</title><style>{CSS}</style></head><body>\n"
            + "\n".join(body) + "\n</body></html>\n")
