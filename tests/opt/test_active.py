"""The solver-in-the-loop machinery (issue 26) on analytic oracles: acquisition, loop, resume, failures."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import norm

from pcmgn_jax.opt import acquisition as acq
from pcmgn_jax.opt.active import ActiveLearningError, LoopConfig, Problem, best_at, fit_surrogate, run_loop
from pcmgn_jax.sim.solver import SolverError

UM = 1e-6


def test_expected_improvement_matches_its_definition_and_is_finite_where_the_std_is_zero():
    rng = np.random.default_rng(0)
    mean, std, best = 1.0, 0.2, 0.9
    samples = rng.normal(mean, std, 400_000)
    mc = np.maximum(best - samples, 0).mean()           # E[max(best - f, 0)], f ~ N(mean, std²)
    assert acq.expected_improvement([mean], [std], best)[0] == pytest.approx(mc, rel=1e-2)
    got = acq.expected_improvement([0.5, 1.5, 0.5], [0.0, 0.0, 1e-300], 1.0)
    np.testing.assert_allclose(got, [0.5, 0.0, 0.5])     # sure candidates: the plain improvement, no 0/0
    z = (best - mean) / std
    assert acq.expected_improvement([mean], [std], best)[0] == pytest.approx(
        (best - mean) * norm.cdf(z) + std * norm.pdf(z))
    with pytest.raises(ValueError, match="negative std"):
        acq.expected_improvement([1.0], [-1.0], 1.0)


def test_propose_prefers_uncertain_low_candidates_and_respects_exclusions():
    mean, std = np.array([1.0, 1.0, 0.95]), np.array([0.0, 0.3, 0.0])
    assert acq.propose(mean, std, 1.0, "ei") == 1              # the uncertain one can improve more
    assert acq.propose(mean, std, 1.0, "mean") == 2
    assert acq.propose(mean, std, 1.0, "lcb") == 1             # 1 - 2 * 0.3 < 0.95
    assert acq.propose(mean, std, 1.0, "ei", exclude=[False, True, False]) == 2
    with pytest.raises(ValueError, match="every candidate"):
        acq.propose(mean, std, 1.0, exclude=[True] * 3)


def _one_d(x0=0.3e-3):
    """1-D: f(x) = 1 + ((x - x0) / 0.1 mm)² on [0.05, 0.6] mm, optimum 1 at x0."""
    return Problem(names=("T",), low=(0.05e-3,), high=(0.6e-3,), band=None,
                   oracle=lambda d: np.array([1.0 + ((d[0] - x0) / 1e-4) ** 2]),
                   reference={"design_um": [x0 / UM], "mpa": 1.0})


def test_gp_ei_finds_a_known_1d_optimum(tmp_path):
    log = run_loop(_one_d(), LoopConfig(budget=10, n_init=3), tmp_path / "a.json", progress=False)
    best = log["rounds"][-1]["best"]
    assert abs(best["design_um"][0] - 300.0) < 3.0        # within 3 µm of x0 on a 550 µm interval
    assert best["gap_pct"] < 0.1
    assert log["rounds"][-1]["solver_runs"] == 10
    assert best_at(log, 3)["solver_runs"] == 3 and best_at(log, 2) is None


def _quadratic_2d(calls=None, fail_at=None, exc=SolverError):
    def f(d):
        if calls is not None:
            calls.append(tuple(d))
            if fail_at is not None and len(calls) == fail_at:
                raise exc("energy error too large (a test)")
        return np.array([1.0 + ((d[0] - 120e-6) / 1e-4) ** 2 + 0.5 * ((d[1] - 100e-6) / 1e-4) ** 2])
    return Problem(names=("OCA1", "OCA2"), low=(50e-6,) * 2, high=(150e-6,) * 2, oracle=f,
                   holdout=(np.array([[80e-6, 90e-6], [130e-6, 110e-6]]),
                            np.array([1.165, 1.095])))


def _strip(log):
    return [{k: v for k, v in r.items() if k != "seconds"} for r in log["rounds"]]


def test_resume_after_a_kill_replays_the_rounds_exactly(tmp_path):
    cfg = LoopConfig(surrogate="kriging", budget=9, n_init=4, batch=2)
    whole = run_loop(_quadratic_2d(), cfg, tmp_path / "whole.json", progress=False)
    calls = []
    with pytest.raises(KeyboardInterrupt):     # a kill in round 2's second design
        run_loop(_quadratic_2d(calls, fail_at=8, exc=KeyboardInterrupt), cfg, tmp_path / "cut.json", progress=False)
    assert [r["round"] for r in json.loads((tmp_path / "cut.json").read_text())["rounds"]] == [0, 1]
    calls2 = []
    resumed = run_loop(_quadratic_2d(calls2), cfg, tmp_path / "cut.json", progress=False)
    assert _strip(resumed) == _strip(whole)
    assert len(calls2) == 9 - 6                # the finished rounds were not re-run
    # a larger budget goes on from the finished log; another config is refused, naming the field
    more = run_loop(_quadratic_2d(), LoopConfig(surrogate="kriging", budget=11, n_init=4, batch=2),
                    tmp_path / "cut.json", progress=False)
    assert _strip(more)[:len(whole["rounds"])] == _strip(whole) and more["rounds"][-1]["solver_runs"] == 11
    with pytest.raises(ActiveLearningError, match="acquisition"):
        run_loop(_quadratic_2d(), LoopConfig(acquisition="lcb", budget=9, n_init=4, batch=2), tmp_path / "cut.json",
                 progress=False)


def test_a_solver_failure_is_named_and_keeps_every_finished_round(tmp_path):
    calls = []
    path = tmp_path / "fail.json"
    with pytest.raises(ActiveLearningError, match=r"round 2: the solver failed at design .*SolverError"):
        run_loop(_quadratic_2d(calls, fail_at=6), LoopConfig(budget=8, n_init=4), path, progress=False)
    rounds = json.loads(path.read_text())["rounds"]
    assert [r["round"] for r in rounds] == [0, 1] and rounds[-1]["solver_runs"] == 5
    assert rounds[1]["holdout_error"]["n"] == 2 and np.isfinite(rounds[1]["holdout_error"]["mae_pct"])


def test_auto_picks_the_exact_model_and_mgn_corrects_its_base_with_the_residuals():
    rng = np.random.default_rng(1)
    X = rng.uniform(-1, 1, (12, 2))
    y = 1 + 0.3 * X[:, 0] - 0.2 * X[:, 1] + 0.4 * X[:, 0] * X[:, 1] + 0.1 * X[:, 1] ** 2
    predict, info = fit_surrogate("auto", X, y, ("a", "b"))
    assert info["mop"]["chosen"] == "quadratic" and info["mop"]["cop"]["quadratic"] == pytest.approx(1, abs=1e-9)
    q = rng.uniform(-1, 1, (5, 2))
    mean, std = predict(q)
    truth = 1 + 0.3 * q[:, 0] - 0.2 * q[:, 1] + 0.4 * q[:, 0] * q[:, 1] + 0.1 * q[:, 1] ** 2
    np.testing.assert_allclose(mean, truth, atol=1e-9)
    assert np.all(std >= 0)
    # a base off by a constant: the residual GP takes the offset out
    predict, info = fit_surrogate("mgn", X, y, ("a", "b"), base=lambda r: 1 + 0.3 * r[:, 0] - 0.2 * r[:, 1]
                                  + 0.4 * r[:, 0] * r[:, 1] + 0.1 * r[:, 1] ** 2 + 0.05)
    assert info["residual_rms_mpa"] == pytest.approx(0.05)
    np.testing.assert_allclose(predict(q)[0], truth, atol=1e-4)


def test_the_robust_problem_averages_the_cases_and_keeps_the_band_on_two_variables():
    seen = []

    def f(d):
        seen.append(d)
        return np.array([1.0, 2.0, 3.0]) + d[2] / 1e-4
    p = Problem(names=("OCA1", "OCA2", "POL"), low=(50e-6, 50e-6, 30e-6), high=(150e-6, 150e-6, 70e-6), oracle=f,
                band_vars=("OCA1", "OCA2"), cases=({"r": 1.0}, {"r": 2.0}, {"r": 3.0}))
    c = p.candidates()
    s = c[:, 0] + c[:, 1]
    assert len(c) > 1000 and s.min() >= 150e-6 - 1e-12 and s.max() <= 250e-6 + 1e-12
    assert c[:, 2].min() < 35e-6 and c[:, 2].max() > 65e-6     # POL is not in the sum band
    rows = p.rows(c[:2])
    assert rows.shape == (6, 4) and rows[:3, 3].tolist() == [1.0, 2.0, 3.0]
    with pytest.raises(ValueError, match="budget 4 is below"):
        LoopConfig(budget=4, n_init=2).check(3)


def test_the_comparison_table_names_every_strategy_and_budget():
    from pcmgn_jax.opt.active_tasks import table_markdown
    rows = [{"strategy": s, "budget": b, "seed": 0, "gap_pct": g, "holdout_mae_pct": 0.1}
            for s, g0 in (("gp-ei", 0.0), ("mgn-ei", 1.3)) for b, g in ((8, g0), (16, g0 / 2))]
    md = table_markdown({"reference": {"mpa": 0.98, "design_um": [150, 100]}, "budgets": [8, 16], "seeds": [0],
                         "context": {"preset": "cpu", "reading": "area_mean"}, "strategies": ["gp-ei", "mgn-ei"],
                         "rows": rows, "hit_pct": 0.3,
                         "runs_to_hit": [{"strategy": "gp-ei", "seed": 0, "runs": 5},
                                         {"strategy": "mgn-ei", "seed": 0, "runs": None}]}, "cmd")
    assert "| gp-ei | +0.00 (+0.00) | +0.00 (+0.00) | 5 | 0.100 |" in md
    assert "| mgn-ei | +1.30 (+1.30) | +0.65 (+0.65) | not reached | 0.100 |" in md and md.startswith("`cmd`")
