"""Normalisation statistics (pcmgn_jax.mgn.normalization, train.setup.compute_stats) against NumPy references."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fixtures.helpers import tiny_config
from pcmgn_jax.mgn.formulation import FORMULATIONS, is_ball
from pcmgn_jax.mgn.normalization import Accumulator, TypedAccumulator, denormalize_output, normalize_target
from pcmgn_jax.train.sampling import pair_table, sample
from pcmgn_jax.train.setup import prepare


def test_accumulators_match_numpy_with_offset_data():
    rng = np.random.default_rng(0)
    x = 5e-3 + 1e-7 * rng.normal(size=(3000, 3))  # µm spread on a mm offset: the shifted sums keep it
    types = rng.integers(0, 4, 3000)
    types[types == 3] = 2  # type 3 gets no samples -> falls back to all-node statistics
    acc, typed = Accumulator(3), TypedAccumulator(4, 3)
    for chunk in np.array_split(np.arange(3000), 7):
        acc.add(x[chunk])
        typed.add(x[chunk], types[chunk])
    m, s = acc.result()
    np.testing.assert_allclose(m, x.mean(0), rtol=1e-12)
    np.testing.assert_allclose(s, x.std(0), rtol=1e-6)
    pm, ps = typed.result(per_part=True)
    for k in range(3):
        np.testing.assert_allclose(pm[k], x[types == k].mean(0), rtol=1e-12)
        np.testing.assert_allclose(ps[k], x[types == k].std(0), rtol=1e-6)
    np.testing.assert_allclose(pm[3], x.mean(0), rtol=1e-12)
    gm, gs = typed.result(per_part=False)
    assert np.all(gm == gm[0]) and np.all(gs == gs[0])
    z = Accumulator(2)
    z.add(np.ones((5, 2)))
    assert np.all(z.result()[1] == 1.0)  # zero-variance guard


@pytest.mark.parametrize("name", ["paper", "default"])
def test_target_statistics_match_numpy_reference(tiny_trajs, name):
    cfg = tiny_config(formulation=name, noise_std=0.0)
    setup = prepare(cfg, tiny_trajs[:3])
    form = FORMULATIONS[name]
    topo = setup.graphs[0].topology  # one mesh: every trajectory shares it
    node_type = np.asarray(topo.node_type)
    free = ~np.asarray(topo.fixed)
    moving = free & ~(is_ball(node_type) & form.rigid_ball)
    rows = [sample(form, tiny_trajs[i], int(t), setup.spec.sim.dt) for i, t in pair_table(tiny_trajs[:3])]
    tgt = np.stack([r["target"] for r in rows])  # (P, N, 3)
    stats = setup.stats
    for k in np.unique(node_type):
        sel_m = moving & (node_type == k) if name == "default" else moving
        sel_s = (node_type == k) if name == "default" else np.ones_like(moving)
        if sel_m.any() and tgt[:, sel_m, :2].std() > 0:
            np.testing.assert_allclose(stats.target_mean[k, :2], tgt[:, sel_m, :2].mean((0, 1)), rtol=2e-5,
                                       atol=1e-12)
        np.testing.assert_allclose(stats.target_mean[k, 2], tgt[:, sel_s, 2].mean(), rtol=2e-5)
        np.testing.assert_allclose(stats.target_std[k, 2], tgt[:, sel_s, 2].std(), rtol=2e-5)
    if form.rigid_ball:
        b = np.stack([r["ball"] for r in rows])
        np.testing.assert_allclose(stats.ball_mean, b.mean(0), rtol=2e-5, atol=1e-9)
    # normalise / denormalise are inverse
    t = jnp.asarray(tgt[3], jnp.float32)
    back = denormalize_output(stats, node_type, normalize_target(stats, node_type, t))
    np.testing.assert_allclose(np.asarray(back), tgt[3], rtol=1e-5, atol=1e-12 + 1e-5 * np.abs(tgt[3]).max())


@pytest.mark.slow   # 19 s: trains a tiny run (the default suite stays under 10 minutes)
def test_a_parts_own_material_is_normalised_across_parts(tiny_trajs, tmp_path):
    """``material`` is one number per part: with ``per_part`` normalisation it still takes the all-node
    statistics (a per-part normaliser would send it to 0 on every training node), so the normalised
    channel tells the parts apart, and a run with the layers known only by it trains to a finite loss."""
    from pcmgn_jax.mgn.normalization import normalize_graph
    from pcmgn_jax.mgn.rollout import input_graph
    from pcmgn_jax.mgn.scene_features import material_rows
    from pcmgn_jax.train import loop as training

    cfg = tiny_config(scene_features="material", part_identity="material", noise_std=0.0, num_steps=20,
                      steps_per_dispatch=10, ckpt_every=20, val_every=20, log_every=10)
    setup = prepare(cfg, tiny_trajs[:3])
    g = setup.graphs[0]
    node_type = np.asarray(g.topology.node_type)
    mat = material_rows(tiny_trajs[0].meta["scene"], node_type).astype(np.float64)
    end = setup.stats.node_mean.shape[1] - setup.spec.sim.formulation.node_extra  # the ball state comes last
    mean, std = (np.asarray(a)[:, end - 3:end] for a in (setup.stats.node_mean, setup.stats.node_std))
    assert np.all(mean == mean[0]) and np.all(std == std[0])  # one row for every part
    np.testing.assert_allclose(mean[0], mat.mean(0), rtol=1e-5)
    np.testing.assert_allclose(std[0], mat.std(0), rtol=1e-4)
    z = np.zeros((len(node_type), 2), np.float32)
    raw, _ = input_graph(setup.spec.sim.formulation, g.topology, g.index, tiny_trajs[0].points, z, z)
    nodes = np.asarray(normalize_graph(setup.stats, raw, node_type).nodes)
    col = g.topology.n_node_types + end - 3  # log10 E, after the one-hot columns
    per_part = {int(t): nodes[node_type == t, col] for t in np.unique(node_type)}
    assert len({round(float(v[0]), 4) for v in per_part.values()}) >= 3  # ball, CG, PLATE differ
    assert all(np.all(np.abs(v) < 5) for v in per_part.values())  # O(1)
    summary = training.train(cfg, tmp_path / "run", train_trajs=tiny_trajs[:3], val_trajs=tiny_trajs[3:])
    assert summary["step"] == cfg.num_steps  # a non-finite loss stops training with an error
    assert all(np.all(np.isfinite(np.asarray(a))) for a in jax.tree.leaves(summary["state"].params))
