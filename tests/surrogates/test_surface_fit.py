"""pcmgn_jax.surrogates.surface_fit (kriging, MOP with CoP) and pcmgn_jax.surrogates.rom against known answers."""
import dataclasses
import warnings

import numpy as np
import pytest

from fixtures.helpers import drop_last_column, make_synthetic_trajectory
from pcmgn_jax.surrogates import surface_fit as rs, surface_kind
from pcmgn_jax.surrogates.regression import FieldRegression
from pcmgn_jax.surrogates.rom import POD_ENERGY, Rom


def _quadratic_data(n=12, m=5, seed=0):
    """x (n, 2) [SI-like], a quadratic field Y (n, m) of x and a linear scalar, and the truth at queries."""
    rng = np.random.default_rng(seed)
    x = np.column_stack([rng.uniform(1e-3, 3e-3, n), rng.uniform(2.0, 6.0, n)])
    c = rng.normal(size=(6, m))

    def field(q):
        a, b = (q[:, 0] - 2e-3) / 1e-3, (q[:, 1] - 4.0) / 2.0
        return np.column_stack([np.ones(len(q)), a, b, a * a, a * b, b * b]) @ c
    xq = np.column_stack([rng.uniform(1.2e-3, 2.8e-3, 4), rng.uniform(2.5, 5.5, 4)])
    return x, field(x), xq, field(xq)


def test_quadratic_field_exact_by_quadratic_and_close_by_kriging():
    x, Y, xq, Yq = _quadratic_data()
    names = ("a", "b")
    mop = rs.MOP(x, {"f": Y, "s": Y[:, 0]}, names=names)
    assert mop.choice["f"] == "quadratic" and mop.cop["f"]["quadratic"] == pytest.approx(1.0, abs=1e-10)
    got = mop.predict(xq)
    np.testing.assert_allclose(got["f"], Yq, atol=1e-9 * np.abs(Yq).max())
    assert got["s"].shape == (4,)
    k = rs.Kriging(x, {"f": Y}, names=names)
    mean, std = k.predict(xq, return_std=True)
    assert mean["f"].shape == std["f"].shape == Yq.shape and np.all(std["f"] >= 0)
    assert np.abs(mean["f"] - Yq).max() < 0.03 * np.ptp(Y)
    report = mop.report()
    assert set(report["f"]["cop"]) == set(rs.CANDIDATES)
    assert all(isinstance(v, float) for v in report["f"]["cop"].values())
    assert report["f"]["cop"]["linear"] < report["f"]["cop"]["quadratic"]


def test_mop_prefers_the_simpler_exact_model_and_reports_too_few_samples():
    x = np.linspace(0.0, 1.0, 3)[:, None]
    mop = rs.MOP(x, {"y": 2 * x[:, 0] + 1}, names=("p",))
    assert mop.choice["y"] == "linear"
    assert mop.cop["y"]["linear"] == pytest.approx(1.0) and mop.cop["y"]["quadratic"] is None
    why = mop.report()["y"]["not_applicable"]["quadratic"]
    assert "needs >= 4 training samples" in why and "got 3" in why
    np.testing.assert_allclose(mop.predict([[0.25]])["y"], [1.5])


def test_cop_perfect_mean_and_constant():
    y = np.array([1.0, 2.0, 4.0, 7.0])
    assert rs.coefficient_of_prognosis(y, y) == 1.0
    assert rs.coefficient_of_prognosis(y, np.full(4, y.mean())) == pytest.approx(0.0, abs=1e-15)
    # the leave-one-out mean predictor: residual (y_i - mean) n / (n - 1), so CoP = 1 - (n / (n - 1))²
    loo = rs.loo_predictions(lambda z, Y: (lambda q: Y.mean(0)), np.arange(4.0)[:, None], y[:, None])
    assert rs.coefficient_of_prognosis(y[:, None], loo) == pytest.approx(1 - (4 / 3) ** 2)
    assert rs.coefficient_of_prognosis(np.full(4, 3.0), np.full(4, 3.0)) is None   # SST = 0: undefined
    mop = rs.MOP(np.arange(5.0)[:, None], {"c": np.full(5, 3.0)}, names=("p",))
    assert all(v is None for v in mop.cop["c"].values())
    assert "SST = 0" in mop.reasons["c"]["kriging"]
    np.testing.assert_allclose(mop.predict([[2.5]])["c"], [3.0])


def test_field_surfaces_on_a_shared_mesh(tiny_trajs):
    """The synthetic fields are linear in the design: MOP picks linear and predicts a new design exactly."""
    truth = make_synthetic_trajectory(1.0)
    d = FieldRegression("none", [truth]).x
    mop = surface_kind.FieldSurface("mop", tiny_trajs)
    assert mop.model.choice == {"u": "linear", "vm": "linear"}
    u, vm = mop.predict(d)
    assert u.shape == (1,) + truth.displacement.shape and vm.shape == (1,) + truth.von_mises.shape
    np.testing.assert_allclose(u[0], truth.displacement, atol=1e-9 * np.abs(truth.displacement).max())
    np.testing.assert_allclose(vm[0], truth.von_mises, atol=1e-9 * truth.von_mises.max())
    k = surface_kind.FieldSurface("kriging", tiny_trajs)
    u, vm = k.predict(d)
    assert np.abs(u[0] - truth.displacement).max() < 0.02 * np.abs(truth.displacement).max()
    assert np.abs(vm[0] - truth.von_mises).max() < 0.02 * truth.von_mises.max()
    assert k.predict_std(d)[0].shape == u.shape and not k.warnings
    s = surface_kind.ObjectiveSurface("mop", tiny_trajs, readings=("area_mean",), part=1)
    got = s.predict_trajectories([truth])["area_mean"]
    assert got == pytest.approx(rs.objective_table([truth], ("area_mean",), part=1)["area_mean"], rel=1e-9)


def _scene(design, speed, *, drop=False, name=None):
    """A synthetic family scene: the fields scale with the drop speed; ``drop``: one column fewer."""
    t = make_synthetic_trajectory(design)
    s = speed / 3.0
    meta = {**t.meta, "name": name or f"d{design}_v{speed}",
            "scene_params": {"CG": t.meta["design"]["CG"], "ball.velocity": speed}}
    t = dataclasses.replace(t, displacement=t.displacement * s, velocity=t.velocity * s,
                            von_mises=t.von_mises * s, meta=meta)
    return drop_last_column(t) if drop else t


@pytest.fixture(scope="module")
def family():
    train = [_scene(d, v, drop=i % 2 == 1) for i, (d, v) in
             enumerate([(1.0, 3.0), (0.8, 2.0), (1.2, 2.0), (0.8, 4.0), (1.2, 4.0), (1.0, 2.5), (0.9, 3.5)])]
    return train, Rom(train)


def test_rom_reproduces_training_snapshots(family):
    train, rom = family
    assert rom.ref is train[0] and rom.pod.n_modes >= 1 and rom.pod.energy_kept >= POD_ENERGY
    us, vms = rom.predict_trajectories(train[:2])
    for t, u, vm in zip(train[:2], us, vms):
        assert u.shape == t.displacement.shape and vm.shape == t.von_mises.shape
        # the snapshot carried to the reference mesh and back: what the rom can reproduce at best
        back = rom._carry(train[0], t, *rom._carry(t, train[0], t.displacement, t.von_mises))
        tol_u, tol_vm = 1e-6 * np.abs(t.displacement).max(), 1e-6 * t.von_mises.max()
        assert np.abs(u - back[0]).max() < tol_u and np.abs(vm - back[1]).max() < tol_vm
        assert np.abs(u - t.displacement).max() < tol_u and np.abs(vm - t.von_mises).max() < tol_vm
    assert not rom.warnings


def test_rom_missing_parameter_and_out_of_range(family):
    train, rom = family
    bad = _scene(1.0, 3.0, name="no_speed")
    bad.meta["scene_params"] = {"CG": bad.meta["scene_params"]["CG"]}
    with pytest.raises(ValueError, match=r"no_speed.*'ball\.velocity' missing"):
        rom.predict_trajectories([bad])
    with pytest.raises(ValueError, match="'ball.velocity' missing"):
        surface_kind.ObjectiveSurface("kriging", train, readings=("area_mean",), part=1).predict_trajectories([bad])
    fast = _scene(1.0, 6.0, name="too_fast")
    with pytest.warns(rs.ExtrapolationWarning, match="too_fast"):
        us, _ = rom.predict_trajectories([fast])
    assert us[0].shape == fast.displacement.shape and np.all(np.isfinite(us[0]))
    assert len(rom.warnings) == 1 and "ball.velocity = 6" in rom.warnings[0] and "extrapolated" in rom.warnings[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rom.predict_trajectories([fast])                # recorded once, not warned again
    assert len(rom.warnings) == 1


def test_held_fixed_parameter_is_named():
    box = rs.ParameterBox([[1.0, 5.0], [2.0, 5.0]], ("a", "b"), model="kriging")
    with pytest.warns(rs.ExtrapolationWarning):
        assert box.scale([[1.5, 6.0]], ["s1"]).tolist() == [[0.0]]
    assert "s1: b = 6 outside" in box.warnings[0] and "held fixed" in box.warnings[0]
    with pytest.raises(ValueError, match="every parameter"):
        rs.ParameterBox([[1.0], [1.0]], ("a",), model="rom")
    with pytest.raises(ValueError, match="quantity 'q' must be"):
        rs.Kriging([[0.0], [1.0], [2.0]], {"q": np.zeros(2)}, names=("a",))


def test_zero_shot_scene_is_named(family):
    """A number training held fixed (the plate's modulus) or a new scene parameter: answered, and named."""
    train, _ = family
    rom = Rom(train)
    stiff = _scene(1.0, 3.0, name="stiff_plate")
    stiff.meta["scene"] = {**stiff.meta["scene"], "layers": [dict(layer, youngs=2 * layer["youngs"])
                                                             if layer["name"] == "PLATE" else layer
                                                             for layer in stiff.meta["scene"]["layers"]]}
    new = _scene(1.0, 3.0, name="new_param")
    new.meta["scene_params"] = {**new.meta["scene_params"], "PLATE": 500e-6}
    with pytest.warns(rs.ExtrapolationWarning):
        us, _ = rom.predict_trajectories([stiff, new])
    assert len(us) == 2
    assert any("stiff_plate: PLATE.youngs = 1.378e+11" in w and "held fixed" in w for w in rom.warnings)
    assert any("new_param: scene parameter PLATE = 0.0005 unknown" in w for w in rom.warnings)
    assert len(rom.warnings) == 2


def test_evaluation_baselines_score_every_kind(tiny_trajs, family):
    """baseline_metrics: every kind answers (numbers) or says why not, scored by the caller's own function;
    kriging/mop score the objective directly (the synthetic objective is linear in the design: MOP exact)
    and their field surfaces on a shared mesh (the synthetic panel has no OLED: fields only); across meshes only rom
    gives fields, and a zero-shot or out-of-box query is listed under ``warnings``."""
    from pcmgn_jax import metrics
    from pcmgn_jax.eval.baselines import BASELINES, baseline_metrics

    def scores(pu, pv, test):
        return metrics.field_metrics(pu, pv, [t.displacement for t in test], [t.von_mises for t in test])

    test = [make_synthetic_trajectory(1.0), make_synthetic_trajectory(1.1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = baseline_metrics(tiny_trajs, test, lambda u, v: scores(u, v, test))
    assert set(b) == set(BASELINES)
    assert b["poly2"]["position_mae_um"] < 1e-6 and b["mop"]["position_mae_um"] < 1e-6  # linear fields
    assert b["mop"]["mop_fields"] == {"u": "linear", "vm": "linear"}
    assert "no part named 'OLED'" in b["kriging"]["objective"]   # the synthetic panel has no OLED layer
    assert b["none"]["position_mae_um"] > 0 and "fit_seconds" in b["rom"] or "not_applicable" in b["rom"]
    train, _ = family
    far = [_scene(1.0, 6.0, drop=True, name="fast")]   # speed outside the training box (2..4 m/s)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = baseline_metrics(train, far, lambda u, v: scores(u, v, far), kinds=("poly2", "kriging", "rom"))
    assert "shared topology" in b["poly2"]["not_applicable"]
    assert "not_applicable" in b["kriging"]   # no OLED for the objective, no shared mesh for the fields
    assert np.isfinite(b["rom"]["position_mae_um"])
    assert any("fast" in w for w in b["rom"]["warnings"])
    with pytest.raises(ValueError, match="baseline must be one of"):
        baseline_metrics(train, far, lambda u, v: {}, kinds=("krigging",))
