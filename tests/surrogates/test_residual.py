"""residual_of: the MGN as a learned correction of a baseline's fields (pcmgn_jax/surrogates/residual.py,
correction.py)."""
import dataclasses
import json

import numpy as np
import pytest

from fixtures.helpers import make_synthetic_trajectory, tiny_config
from pcmgn_jax.mgn.formulation import is_ball
from pcmgn_jax.surrogates import correction, residual
from pcmgn_jax.surrogates.rom import Rom


@pytest.fixture(scope="module")
def scenes():
    """Six synthetic scenes (each its own mesh); their fields are scaled by a wiggly function of the design,
    so a rom fitted without a scene has a residual there."""
    def scene(d):
        t, f = make_synthetic_trajectory(d), np.exp(3 * (d - 1)) * (1 + 0.3 * np.cos(12 * d))
        return dataclasses.replace(t, displacement=t.displacement * f, von_mises=t.von_mises * f)
    return [scene(d) for d in (0.8, 0.9, 1.0, 1.1, 1.25, 1.4)]


def test_out_of_fold_fields_come_from_a_baseline_without_the_scene(scenes):
    us, vms = residual.out_of_fold_fields("rom", scenes)
    for i in (0, 3):
        others = Rom([t for j, t in enumerate(scenes) if j != i])
        u, vm = others.predict_trajectories([scenes[i]])
        np.testing.assert_allclose(us[i], u[0], rtol=1e-12, atol=0)
        np.testing.assert_allclose(vms[i], vm[0], rtol=1e-12, atol=0)
    # the in-sample rom reproduces its snapshots (residual ~0); out of fold it does not
    u_in, _ = Rom(scenes).predict_trajectories(scenes[3:4])
    scale = np.abs(scenes[3].displacement).max()
    assert np.abs(u_in[0] - scenes[3].displacement).max() < 1e-4 * scale
    assert np.abs(us[3] - scenes[3].displacement).max() > 1e-2 * scale
    k2, _ = residual.out_of_fold_fields("rom", scenes, folds=2)   # fold i % 2: fitted on the other parity
    u_odd, _ = Rom(scenes[0::2]).predict_trajectories([scenes[3]])
    np.testing.assert_allclose(k2[3], u_odd[0], rtol=1e-12, atol=0)


def test_residual_round_trip_keeps_the_ball(scenes):
    t = scenes[2]
    rng = np.random.default_rng(0)
    bu, bvm = rng.normal(size=t.displacement.shape) * 1e-6, rng.normal(size=t.von_mises.shape) * 1e6
    (r,) = correction.residual_trajectories([t], [bu], [bvm])
    ball = is_ball(t.node_type)
    np.testing.assert_array_equal(r.displacement[:, ball], t.displacement[:, ball])   # the dynamical state
    np.testing.assert_allclose(r.displacement[:, ~ball], t.displacement[:, ~ball] - bu[:, ~ball])
    np.testing.assert_allclose(r.von_mises, t.von_mises - bvm)
    assert r.meta["residual_of_baseline"] and "residual_of_baseline" not in t.meta
    (u,), (vm,) = correction.corrected([t], [r.displacement], [r.von_mises], [bu], [bvm])
    np.testing.assert_allclose(u, t.displacement, atol=1e-18)
    np.testing.assert_allclose(vm, t.von_mises, atol=1e-6)
    with pytest.raises(ValueError, match="do not match"):
        correction.corrected([t], [r.displacement], [r.von_mises], [bu[:, :-1]], [bvm])


def test_residual_splits_validation_uses_the_whole_training_fit(scenes):
    train_r, val_r = residual.residual_splits("rom", scenes[:5], scenes[5:])
    u, vm = Rom(scenes[:5]).predict_trajectories(scenes[5:])
    panel = ~is_ball(scenes[5].node_type)
    np.testing.assert_allclose(val_r[0].displacement[:, panel], scenes[5].displacement[:, panel] - u[0][:, panel])
    assert len(train_r) == 5 and residual.residual_splits("rom", scenes[:5], [])[1] == []
    with pytest.raises(ValueError, match="no such baseline"):
        residual.fit_baseline("kriging", scenes)
    with pytest.raises(ValueError, match="at least 2"):
        residual.out_of_fold_fields("rom", scenes[:1])


def test_config_names_what_a_residual_run_needs():
    cfg = tiny_config(residual_of="rom")
    assert cfg.formulation.contact_projection and not cfg.scan_formulation.contact_projection
    assert tiny_config().scan_formulation == tiny_config().formulation
    with pytest.raises(ValueError, match="residual_of"):
        tiny_config(residual_of="poly3")
    with pytest.raises(ValueError, match="residual_of.*lambda_pen=10"):
        tiny_config(residual_of="rom", lambda_pen=10.0)
    with pytest.raises(ValueError, match="residual_of.*quasi_static"):
        tiny_config(residual_of="rom", formulation="dynamic")
    with pytest.raises(ValueError, match="residual_of.*stress_target='log'"):   # a residual stress is signed
        tiny_config(residual_of="rom", stress_target="log")


@pytest.mark.slow  # ~60 s: a tiny training run and its evaluation
def test_residual_run_trains_and_reports_the_corrected_fields(scenes, tmp_path):
    from pcmgn_jax.eval.evaluate import evaluate
    from pcmgn_jax.surrogates.registry import fit
    from pcmgn_jax.train import loop as training
    cfg = tiny_config(residual_of="rom", num_steps=40, val_every=40, ckpt_every=40)
    train, val = residual.residual_splits("rom", scenes[:4], scenes[4:5])
    training.train(cfg, tmp_path, train_trajs=train, val_trajs=val)
    (tmp_path / "config.json").write_text(json.dumps(cfg.to_dict()))
    m = evaluate(tmp_path, test_trajs=scenes[5:], train_trajs=scenes[:4], plot=False)
    assert m["residual_of"] == "rom" and m["contact_projection"] and np.isfinite(m["position_mae_um"])
    mgn = fit("mgn", scenes[:4], workdir=tmp_path, ref=scenes[5])
    u, vm = mgn.rollout_trajectories(scenes[5:])
    base_u, base_vm = Rom(scenes[:4]).predict_trajectories(scenes[5:])
    # the corrected field is the baseline plus a bounded correction, not a field rebuilt from scratch
    panel = ~is_ball(scenes[5].node_type)
    gap = np.abs(np.asarray(u)[0][:, panel] - base_u[0][:, panel]).max()
    assert gap < np.abs(scenes[5].displacement).max()
    ball = is_ball(scenes[5].node_type)   # residual_ball='baseline': the ball follows the rom's ball
    path_u, _ = correction.ball_path(scenes[5], base_u[0], mgn.sim.spec.dt)
    np.testing.assert_allclose(np.asarray(u)[0][1:, ball], path_u[:, ball], atol=1e-12)
    assert m["residual_ball"] == "baseline"
    with pytest.raises(ValueError, match="residual"):
        mgn.predict(np.array([[100e-6]]))


def test_rigid_contact_makes_the_ball_rigid_and_removes_the_overlap(scenes):
    """A prediction whose ball sinks 5 µm into a panel that does not move: rigid_contact (the rollout's
    contact rule, also the rom_contact baseline) leaves one rigid ball and no cover-glass node inside it."""
    from pcmgn_jax import metrics
    from pcmgn_jax.eval.evaluate import boundary
    t = scenes[2]
    ball = is_ball(t.node_type)
    u = np.zeros_like(t.displacement)
    gap = t.points[ball, 1].min() - t.points[~ball, 1].max()                  # 10 µm above the cover glass
    u[:, ball, 1] = -(gap + 5e-6) * np.sin(np.linspace(0, np.pi, t.n_frames))[:, None]
    u[:, ball, 0] = 1e-7 * np.arange(ball.sum())                              # a non-rigid ball row
    bn, pn = boundary(t, 1)
    depth = lambda v: metrics.penetration_stats((t.points + v)[:, bn], (t.points + v)[:, pn])["max_um"]  # noqa: E731
    assert depth(u) > 4.0
    fixed = correction.rigid_contact(t, u)
    assert depth(fixed) < 0.05 and np.ptp(fixed[:, ball], axis=1).max() == 0.0
    np.testing.assert_allclose(fixed[:, ball, 1], u[:, ball, 1].mean(axis=1, keepdims=True).repeat(ball.sum(), 1))
    moved = np.abs(fixed - u)[:, ~ball].max(axis=(0, 2)) > 0
    assert moved.any() and not moved[t.points[~ball, 1] < t.points[~ball, 1].max() - 1e-12].any()  # top nodes only
