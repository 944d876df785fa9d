"""Trust figures (issue 26): Spearman on constructed cases, and the ensemble report on a tiny run."""
from __future__ import annotations

import numpy as np
import pytest

from pcmgn_jax.eval.ensemble import _collapse, _node_figures, spearman


def test_spearman_on_constructed_cases():
    e = np.array([0.1, 0.5, 0.2, 3.0, 1.0])
    assert spearman(e * 2 + 1, e)["rho"] == pytest.approx(1.0)            # any increasing map ranks perfectly
    assert spearman(np.exp(-e), e)["rho"] == pytest.approx(-1.0)
    assert spearman([1, 2, 3, 4], [1, 3, 2, 4])["rho"] == pytest.approx(0.8)   # 1 - 6·2 / (4·15)
    assert spearman([1, 2], [1, 2])["rho"] is None                           # too few
    got = spearman([1, 1, 1], [1, 2, 3])
    assert got["rho"] is None and "constant" in got["why"]
    with pytest.raises(ValueError, match="shape"):
        spearman([1, 2, 3], [1, 2])
    with pytest.raises(ValueError, match="non-finite"):
        spearman([1, np.nan, 3], [1, 2, 3])


def test_node_figures_and_the_collapse_ratio():
    class T:  # a trajectory with a known displacement
        displacement = np.zeros((2, 3, 2))
    # two members at +-d around a mean off the truth by m: spread = std (ddof 1) = d·√2, error = m
    d, m = 1e-6, np.array([1e-6, 2e-6, 4e-6])
    u0 = np.zeros((2, 3, 2))
    u0[..., 0] = m + d
    u1 = np.zeros((2, 3, 2))
    u1[..., 0] = m - d
    spread, err = _node_figures([[u0], [u1]], [T()])
    np.testing.assert_allclose(spread, np.full(3, np.sqrt(2)), rtol=1e-12)   # µm
    np.testing.assert_allclose(err, m * 1e6, rtol=1e-12)
    assert _collapse(spread, err) == pytest.approx(np.sqrt(2) / (7 / 3))
    assert _collapse(spread, np.zeros(3)) is None


@pytest.mark.slow  # ~13 s (the 10-minute budget); the figures' rules are tested on constructed cases above
def test_ensemble_report_of_identical_members_reports_the_collapse(tiny_run, tiny_trajs):
    """Two copies of one model: zero spread, so ρ is undefined and says why; kriging and the residual GP
    still report their figures on the same designs."""
    from pcmgn_jax.eval.ensemble import ensemble_report
    _, workdir, _ = tiny_run
    rep = ensemble_report([workdir, workdir], {"test": tiny_trajs[3:]}, tiny_trajs[:3], part=1)  # part 1: CG
    s = rep["sets"]["test"]
    assert s["ensemble"]["spread_mpa"] == [0.0] * len(tiny_trajs[3:])
    assert s["ensemble"]["spread_over_error"] == 0.0
    assert s["member_error_pct"][0] == s["member_error_pct"][1] and np.isfinite(s["mean_error_pct"])
    assert all(v >= 0 for v in s["kriging"]["std_mpa"]) and len(s["residual_gp"]["corrected_error_pct"]) == s["n"]


def test_an_optimum_carries_its_spread(tiny_trajs):
    """The residual-GP spread of a model optimum (a stand-in model off the truth by a known function) and
    the kriging posterior std; every spread is finite and >= 0, and a perfect model has a ~0 residual."""
    from pcmgn_jax.metrics import oled_objective_of
    from pcmgn_jax.opt.objectives import FieldObjective
    from pcmgn_jax.opt.spread import optimum_spread
    from pcmgn_jax.surrogates.inputs import design_of
    from pcmgn_jax.surrogates.registry import fit_objective
    train = tiny_trajs[:3]
    truth = {float(design_of(t)[0]): float(oled_objective_of(t, part=1)) for t in train}

    class Model:  # obj(designs) -> (B,) [MPa]
        def __init__(self, off):
            self.off = off

        def __call__(self, d):
            return np.array([truth.get(float(x[0]), 0.0) + self.off * x[0] / 1e-4 for x in np.atleast_2d(d)])
    x = np.array([design_of(tiny_trajs[3])[0]])
    exact = optimum_spread("mgn", Model(0.0), x, train, part=1, reading="area_mean")
    assert exact["source"].startswith("GP of the model's residuals") and exact["train_residual_rms_mpa"] < 1e-12
    off = optimum_spread("mgn", Model(0.05), x, train, part=1, reading="area_mean")
    assert off["train_residual_rms_mpa"] > 0.01 and np.isfinite(off["std_mpa"]) and off["std_mpa"] >= 0

    obj = FieldObjective(fit_objective("kriging", train, readings=("area_mean",), part=1), None, part=1, names=("CG",))
    k = optimum_spread("kriging", obj, x, train, part=1, reading="area_mean")
    assert k["source"] == "kriging posterior std" and k["std_mpa"] > 0   # x is not a training design


def test_residual_spread_corrects_a_smooth_bias_and_reports_each_prediction(tiny_trajs):
    """ResidualSpread on a stand-in model off the truth by a constant: the GP's mean carries the
    correction to a held-out design (corrected error ~0), and the record names every design with its
    objective, ± and error. A perfect model has zero residuals."""
    from pcmgn_jax.eval.ensemble import ResidualSpread, residual_spread_record
    from pcmgn_jax.surrogates.surface_fit import objective_table
    train, test = tiny_trajs[:3], tiny_trajs[3:]
    truth_tr = objective_table(train, ("area_mean",), part=1)["area_mean"]
    truth_te = objective_table(test, ("area_mean",), part=1)["area_mean"]
    spread = ResidualSpread(train, truth_tr * 0.9, part=1)           # the model reads 10 % low
    np.testing.assert_allclose(spread.residual_mpa, 0.1 * truth_tr, rtol=1e-12)
    rec = residual_spread_record(spread, test, truth_te * 0.9, part=1)
    assert rec["error_pct"] == pytest.approx([10.0] * len(test), rel=1e-9)
    assert rec["corrected_mean_error_pct"] < 10.0 and all(s >= 0 for s in rec["std_mpa"])
    assert len(rec["names"]) == len(test) and "training scenes (3)" in rec["source"]
    perfect = ResidualSpread(train, truth_tr, part=1)
    assert np.all(perfect.residual_mpa == 0) and perfect.predict(test)[0] == pytest.approx(0.0, abs=1e-9)
