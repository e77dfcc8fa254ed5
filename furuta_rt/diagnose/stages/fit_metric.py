"""Stage: the held-out fit (furuta_rt.diagnose.stages.gate) — the nominal and the gated augmented model's predictions
of the informative windows, and the verdict of their paired comparison."""

from __future__ import annotations

from furuta_rt.diagnose.judgement import verify
from furuta_rt.diagnose.stages.findings import effects_of
from furuta_rt.diagnose.stages.state import State
from furuta_rt.model.effects import Effects


def stage(s: State) -> State:
    gated, prep = s.gated, s.ctx.prep
    assert gated is not None, "the fit metric reads the prediction gate's windows"
    plan, nominal_p, aug_p = gated.plan, gated.nominal, gated.augmented
    try:
        augmented = effects_of(list(s.found))
    except ValueError:
        augmented = Effects()
    t = prep.t
    fit = {
        "metric": verify.PREDICTION_METRIC, "nominal": nominal_p.nrmse, "augmented": aug_p.nrmse,
        **verify.compare(nominal_p, aug_p),
        "nominal_theta": nominal_p.nrmse_theta, "nominal_phi": nominal_p.nrmse_phi,
        "augmented_theta": aug_p.nrmse_theta, "augmented_phi": aug_p.nrmse_phi,
        "windows": nominal_p.windows, "window_times_s": [float(t[k] - t[0]) for k in plan.starts],
        "horizon_s": plan.horizon * prep.dt, "folds": plan.folds, "candidate_windows": plan.candidates,
        "held_out_from_s": float(t[plan.starts[0]] - t[0]) if plan.starts else float("nan"),
        "train_params": gated.fold_params,
    }
    prediction = {"starts": plan.starts, "horizon": plan.horizon, "augmented": augmented,
                  "substep_hz": gated.substep_hz}
    return s.with_(fit=fit, prediction=prediction)
