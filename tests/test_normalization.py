"""Normalisation statistics (pcmgn_jax.mgn.normalization, train.setup.compute_stats) against NumPy references."""
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import tiny_config
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
