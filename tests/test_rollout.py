"""Rollout: long horizons stay finite, boundary conditions hold, scan == loop, vmap == single, no recompiles."""
import jax
import numpy as np

from conftest import CompileCounter
from pcmgn_jax.mgn import rollout as rl
def _args(t):
    return t.points, t.displacement[0], t.velocity[0], t.von_mises[0]


def test_long_rollout_finite_and_bcs(tiny_run, tiny_trajs):
    _, _, summary = tiny_run
    s, params = summary["setup"], summary["state"]["params"]
    t = tiny_trajs[3]
    n = 5 * (t.n_frames - 1)
    res, _ = rl.rollout_checked(s.spec.sim, n, params, s.stats, s.topology, s.index, *_args(t))
    assert res.displacement.shape == (n + 1, t.n_nodes, 2)
    for a in (res.displacement, res.velocity, res.von_mises):
        assert np.all(np.isfinite(np.asarray(a)))
    fixed, axis = np.asarray(s.topology.fixed), np.asarray(s.topology.axis)
    assert np.all(np.asarray(res.displacement)[:, fixed] == 0)
    assert np.all(np.asarray(res.displacement)[:, axis, 0] == 0)


def test_scan_equals_python_loop_and_vmap(tiny_run, tiny_trajs):
    _, _, summary = tiny_run
    s, params = summary["setup"], summary["state"]["params"]
    t = tiny_trajs[3]
    pts, u, v, vm = _args(t)
    res = rl.rollout(s.spec.sim, 6, params, s.stats, s.topology, s.index, pts, u, v, vm)
    uu, vv = np.float32(u), np.float32(v)
    for k in range(6):
        uu, vv, _, _ = rl.jitted_step(s.spec.sim, params, s.stats, s.topology, s.index, pts, uu, vv)
    np.testing.assert_allclose(np.asarray(res.displacement[-1]), np.asarray(uu), rtol=1e-4, atol=1e-10)
    stack = lambda *a: np.stack(a)  # noqa: E731
    batch = [stack(*x) for x in zip(_args(tiny_trajs[2]), _args(t))]
    rb = rl.rollout_batch(s.spec.sim, 6, params, s.stats, s.topology, s.index, *batch)
    np.testing.assert_allclose(np.asarray(rb.displacement[1]), np.asarray(res.displacement),
                               rtol=1e-4, atol=1e-10)


def test_rollout_no_recompilation(tiny_run, tiny_trajs):
    _, _, summary = tiny_run
    s, params = summary["setup"], summary["state"]["params"]
    rl.rollout(s.spec.sim, 4, params, s.stats, s.topology, s.index, *_args(tiny_trajs[0]))
    with CompileCounter("_rollout") as c:
        for t in tiny_trajs:
            jax.block_until_ready(rl.rollout(s.spec.sim, 4, params, s.stats, s.topology, s.index, *_args(t)))
    assert c.count == 0


def test_evaluate_writes_metrics_and_plots(tiny_run, tiny_trajs):
    import json

    from pcmgn_jax.eval import evaluate as evaluation
    cfg, workdir, _ = tiny_run
    m = evaluation.evaluate(workdir, test_trajs=tiny_trajs[2:], train_trajs=tiny_trajs[:2], plot=True)
    saved = json.loads((workdir / "eval" / "metrics.json").read_text())
    for k in ("position_mae_um", "position_rmse_um", "stress_mae_mpa", "stress_rmse_mpa", "penetration_max_um",
              "rollout_seconds_per_trajectory", "per_frame_position_mae_um_mean", "per_frame_stress_mae_mpa_std"):
        assert k in saved and np.all(np.isfinite(saved[k]))
    assert len(m["per_frame_position_mae_um_mean"]) == tiny_trajs[0].n_frames
    for png in ("deformed_mesh_pred", "pred_truth_error", "contact_zoom", "mae_vs_frame"):
        assert (workdir / "eval" / f"{png}.png").stat().st_size > 1000
