"""The compute curve's fit and crossings (pcmgn_jax/eval/compute_curve.py) on synthetic runs with a known law."""
import json

import numpy as np
import pytest

from experiments import compute_curve as cli_curve
from pcmgn_jax.eval import compute_curve as cc


def _run(root, steps, seed, obj_err_pct, pos, stress, *, kriging=0.05, n_designs=8, rate=5.0):
    """A fake trained + evaluated run whose per-design objective errors are all ``obj_err_pct``."""
    d = root / f"s{steps}_seed{seed}"
    (d / "eval").mkdir(parents=True)
    (d / "config.json").write_text(json.dumps(dict(num_steps=steps, seed=seed)))
    (d / "metrics.jsonl").write_text("\n".join(json.dumps(dict(step=s, steps_per_s=rate)) for s in (0, 100, 200)))
    true = np.linspace(1.0, 1.5, n_designs)
    spread = np.linspace(0.5, 1.5, n_designs)   # per-design errors that average to obj_err_pct
    pred = true * (1 + obj_err_pct * spread / 100)
    base = dict(oled_objective_area_rel_error_pct_mean=kriging, position_mae_um=0.04, stress_mae_mpa=0.5)
    m = dict(oled_objective_area_rel_error_pct_mean=obj_err_pct, position_mae_um=pos, stress_mae_mpa=stress,
             oled_objective_area_true_mpa=true.tolist(), oled_objective_area_pred_mpa=pred.tolist(),
             baselines=dict(kriging=base, none=dict(position_mae_um=10.0), poly2=base))
    (d / "eval" / "metrics.json").write_text(json.dumps(m))
    return d


def test_the_fit_recovers_a_known_power_law_and_its_crossing(tmp_path):
    law = lambda s, a, b: a * s ** -b  # noqa: E731
    runs = [_run(tmp_path, s, 0, law(s, 40.0, 0.5), law(s, 3.0, 0.4), law(s, 20.0, 0.3)) for s in (1000, 4000, 16000)]
    pts = [cc.curve_point(r) for r in runs]
    fit = cc.fit_power_law(pts, cc.OBJECTIVE)
    assert fit.b == pytest.approx(0.5, rel=1e-9) and np.exp(fit.ln_a) == pytest.approx(40.0, rel=1e-9)
    s = cc.summary(pts, gpu_steps_per_s=50.0)
    k = s["metrics"][cc.OBJECTIVE]["baselines"]["kriging"]
    assert k["steps"] == pytest.approx((40.0 / 0.05) ** 2, rel=1e-6)        # 40 s^-1/2 = 0.05
    assert k["cpu_hours"] == pytest.approx(k["steps"] / 5.0 / 3600)
    assert k["gpu_hours"] == pytest.approx(k["steps"] / 50.0 / 3600)
    # an exact law has no residual: the interval collapses onto the crossing
    assert k["p16"] == pytest.approx(k["steps"], rel=1e-3) and k["p84"] == pytest.approx(k["steps"], rel=1e-3)
    assert set(s["metrics"][cc.OBJECTIVE]["baselines"]) == {"kriging", "poly2"}   # those that report it
    assert "none" in s["metrics"]["position_mae_um"]["baselines"]


def test_noisy_points_widen_the_interval_and_a_flat_curve_never_crosses(tmp_path):
    errs = {1000: 3.0, 4000: 2.2, 16000: 2.0}
    runs = [_run(tmp_path, s, 0, e, 0.3, 2.0) for s, e in errs.items()]
    runs.append(_run(tmp_path, 16000, 1, 2.6, 0.3, 2.0))
    m = json.loads((runs[-1] / "eval" / "metrics.json").read_text())
    del m["baselines"]                      # evaluated with --no_baselines: the others' baselines serve
    (runs[-1] / "eval" / "metrics.json").write_text(json.dumps(m))
    s = cc.summary([cc.curve_point(r) for r in runs])
    k = s["metrics"][cc.OBJECTIVE]["baselines"]["kriging"]
    assert k["p16"] < k["steps"] < k["p84"] and k["p84"] / k["p16"] > 2
    assert 0 <= k["bootstrap"]["share_never"] <= 1
    flat = s["metrics"]["position_mae_um"]                                   # the same error at every length
    assert flat["b"] == pytest.approx(0.0, abs=1e-9)
    assert cc.crossing(np.log(flat["a"]), -0.1, 0.04) == np.inf   # rising error, lower target: never


def test_too_few_runs_and_a_missing_evaluation_are_refused(tmp_path):
    pts = [cc.curve_point(_run(tmp_path, s, 0, 2.0, 0.3, 2.0)) for s in (1000, 4000)]
    with pytest.raises(ValueError, match=">= 3 runs"):
        cc.summary(pts)
    (tmp_path / "bare").mkdir()
    (tmp_path / "bare" / "config.json").write_text(json.dumps(dict(num_steps=10)))
    with pytest.raises(FileNotFoundError, match="eval/metrics.json"):
        cc.curve_point(tmp_path / "bare")


def test_the_command_writes_the_page_json_and_plot(tmp_path):
    for s, e in ((1000, 3.0), (4000, 2.0), (16000, 1.5)):
        _run(tmp_path / "runs", s, 0, e, 0.3 * (s / 1000) ** -0.2, 2.0)
    out = tmp_path / "out"
    assert cli_curve.main(["--runs", str(tmp_path / "runs" / "s*"), "--out", str(out)]) == 0
    page = (out / "compute_curve.md").read_text()
    assert "kriging" in page and "s16000_seed0" in page
    data = json.loads((out / "compute_curve.json").read_text())
    assert [r["steps"] for r in data["runs"]] == [1000, 4000, 16000]
    assert (out / "compute_curve.png").stat().st_size > 1000


def test_a_kept_evaluation_enters_the_curve_as_its_run_did(tmp_path):
    """A run whose folder is gone enters by its kept metrics.json (steps and seed given): the same point, the same
    fit, no training rate (the hours use the others'); a malformed spec or a file that is not an evaluation is
    refused by name."""
    runs = [_run(tmp_path / "runs", s, 0, e, 0.3, 2.0) for s, e in ((1000, 3.0), (4000, 2.0), (16000, 1.5))]
    kept = tmp_path / "kept_metrics.json"
    kept.write_text((runs[-1] / "eval" / "metrics.json").read_text())
    whole = cc.summary([cc.curve_point(r) for r in runs])
    mixed = cc.summary([cc.curve_point(r) for r in runs[:2]] + [cc.kept_point(f"16000:0:{kept}")])
    assert mixed["metrics"][cc.OBJECTIVE]["b"] == pytest.approx(whole["metrics"][cc.OBJECTIVE]["b"], rel=1e-12)
    assert mixed["cpu_steps_per_s"] == 5.0 and np.isnan(mixed["runs"][-1]["steps_per_s"])
    out = tmp_path / "out"
    assert cli_curve.main(["--runs", ",".join(map(str, runs[:2])), "--kept", f"16000:0:{kept}",
                           "--out", str(out)]) == 0
    assert "kept evaluation" in (out / "compute_curve.md").read_text()
    for bad in ("16000:kept_metrics.json", "x:0:" + str(kept), "0:0:" + str(kept)):
        with pytest.raises(ValueError, match="STEPS:SEED:PATH"):
            cc.kept_point(bad)
    (tmp_path / "other.json").write_text(json.dumps(dict(position_mae_um=1.0)))
    with pytest.raises(ValueError, match="other.json: no oled_objective_area_rel_error_pct_mean"):
        cc.kept_point(f"16000:0:{tmp_path / 'other.json'}")


@pytest.mark.slow  # 34 s here with its trained fixture; test_rollout's evaluation test stays
def test_evaluate_without_baselines_scores_the_model_only(tiny_run, tiny_trajs):
    from pcmgn_jax.eval import evaluate as evaluation
    _, workdir, _ = tiny_run
    kw = dict(test_trajs=tiny_trajs[3:], train_trajs=tiny_trajs[:3], plot=False)
    bare = evaluation.evaluate(workdir, name="model_only", baselines=False, **kw)
    full = evaluation.evaluate(workdir, name="with_baselines", **kw)
    assert "baselines" not in bare and "kriging" in full["baselines"]
    assert bare["position_mae_um"] == full["position_mae_um"]            # the model's scores do not change
