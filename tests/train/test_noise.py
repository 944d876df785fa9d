"""Training noise (pcmgn_jax.train.noise): per-node levels, drawn statistics, the rigid ball's shared draw,
and that the training loss really runs it (loss depends on the key only when sigma > 0)."""
import jax
import numpy as np
import pytest

from fixtures.helpers import make_synthetic_trajectory
from pcmgn_jax.train.noise import motion_rms, noise_parts_mask, noise_sigma, sample_noise

SIGMA = 0.3e-6


def _parts(n_ball=4000, n_panel=6000):
    node_part = np.concatenate([np.zeros(n_ball, np.int32), np.repeat(np.arange(1, 7), n_panel // 6)])
    fixed = np.zeros(node_part.shape, bool)
    fixed[-(n_panel // 12):] = True
    node_type = np.where(fixed, 7, node_part)
    return node_part, node_type, fixed


@pytest.mark.parametrize("parts", ["none", "ball", "panel", "all"])
def test_noise_statistics_and_zero_elsewhere(parts):
    node_part, node_type, fixed = _parts()
    sigma = noise_sigma(node_type, node_part, fixed, parts=parts, noise_std=SIGMA)
    noise = np.asarray(jax.jit(sample_noise, static_argnames="rigid_ball")(
        jax.random.PRNGKey(1), sigma, node_part == 0, rigid_ball=False), np.float64)
    sel = noise_parts_mask(node_part, parts, fixed=fixed)
    assert np.all(noise[~sel] == 0.0)  # exactly zero on other parts and on fixed nodes
    if sel.any():
        v = noise[sel].ravel()
        assert abs(v.mean()) < 4 * SIGMA / np.sqrt(v.size)
        assert abs(v.std() / SIGMA - 1) < 4 / np.sqrt(2 * v.size)
        assert abs(np.corrcoef(noise[sel, 0], noise[sel, 1])[0, 1]) < 4 / np.sqrt(sel.sum())


def test_relative_noise_scales_with_each_parts_motion():
    trajs = [make_synthetic_trajectory(d) for d in (0.8, 1.2)]
    t = trajs[0]
    n_types = int(t.node_type.max()) + 1
    rms = motion_rms(trajs, n_types)
    du = np.concatenate([np.diff(tr.displacement, axis=0) for tr in trajs], axis=0)
    for k in range(n_types):  # NumPy reference, per type, both components pooled
        np.testing.assert_allclose(rms[k], np.sqrt(np.mean(du[:, t.node_type == k] ** 2)), rtol=1e-12)
    sigma = noise_sigma(t.node_type, t.node_part, t.node_type == 3, parts="all", noise_rel=0.1, rms=rms)
    np.testing.assert_allclose(sigma, np.where(t.node_type == 3, 0, 0.1 * rms[t.node_type]), rtol=1e-6)
    assert sigma[t.node_part == 0].min() > sigma[t.node_part == 2].max()  # the ball moves most
    with pytest.raises(ValueError, match="motion_rms"):
        noise_sigma(t.node_type, t.node_part, t.node_type == 3, parts="all", noise_rel=0.1)
    with pytest.raises(ValueError, match="noise_parts"):
        noise_parts_mask(t.node_part, "some", fixed=t.node_type == 3)


def test_rigid_ball_gets_one_shared_draw_and_keys_matter():
    node_part, node_type, fixed = _parts(50, 60)
    sigma = noise_sigma(node_type, node_part, fixed, parts="all", noise_std=SIGMA)
    ball = node_part == 0
    a = np.asarray(sample_noise(jax.random.PRNGKey(3), sigma, ball, rigid_ball=True))
    assert np.ptp(a[ball], axis=0).max() == 0 and np.abs(a[ball][0]).max() > 0
    assert np.ptp(a[~ball & ~fixed], axis=0).min() > 0
    b = np.asarray(sample_noise(jax.random.PRNGKey(3), sigma, ball, rigid_ball=True))
    c = np.asarray(sample_noise(jax.random.PRNGKey(4), sigma, ball, rigid_ball=True))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


@pytest.mark.slow  # ~15 s: noise is off in the default formulation (the default suite's 10-minute budget)
def test_training_loss_runs_the_noise(tiny_trajs):
    """The training step's loss changes with the key exactly when noise is configured."""
    from fixtures.helpers import one_union, tiny_config
    from pcmgn_jax.train.loop import init_params
    from pcmgn_jax.train.sampling import pair_table
    from pcmgn_jax.train.setup import prepare
    from pcmgn_jax.train.step import loss_fn

    for noise, differs in ((0.0, False), (SIGMA, True)):
        cfg = tiny_config(noise_std=noise, noise_parts="all")
        setup = prepare(cfg, tiny_trajs[:2])
        params = init_params(setup, tiny_trajs[0], 0)
        batch = one_union(setup, tiny_trajs[:2], [pair_table(tiny_trajs[:2])[5]])
        f = lambda key: float(loss_fn(params, setup.spec, setup.stats, batch, key)[0])  # noqa: E731
        assert (f(jax.random.PRNGKey(0)) != f(jax.random.PRNGKey(1))) == differs


def test_panel_noise_is_a_no_op_for_the_quasi_static_panel():
    """The study runner does not retrain noise_parts=panel / all for the default formulation (SAME_AS in
    experiments/study.py) because of this: the quasi-static panel's inputs are drawn at the reference and
    its total-displacement target needs no correction, so noise on the panel's rows changes nothing the
    network or the loss sees; noise on the ball changes its state channels."""
    import jax.numpy as jnp

    from pcmgn_jax.mgn.formulation import FORMULATIONS, add_noise, model_inputs
    form = FORMULATIONS["default"]
    rng = np.random.default_rng(0)
    n, dt = 12, 4e-6
    ball = np.zeros(n, bool)
    ball[:4] = True
    sample = dict(u=jnp.asarray(rng.normal(size=(n, 2)) * 1e-6), v=jnp.asarray(rng.normal(size=(n, 2))),
                  target=jnp.asarray(rng.normal(size=(n, 3))), ball=jnp.zeros(2))
    clean = model_inputs(form, ball, sample["u"], sample["v"])
    panel_noise = jnp.asarray(np.where(ball[:, None], 0.0, rng.normal(size=(n, 2)) * 3e-7))
    noisy = add_noise(form, ball, sample, panel_noise, dt)
    for a, b in zip(model_inputs(form, ball, noisy["u"], noisy["v"]), clean):
        assert np.array_equal(np.asarray(a), np.asarray(b))
    assert np.array_equal(np.asarray(noisy["target"]), np.asarray(sample["target"]))
    assert np.array_equal(np.asarray(noisy["ball"]), np.asarray(sample["ball"]))
    ball_noise = jnp.asarray(np.where(ball[:, None], 3e-7, 0.0) * np.array([0.0, 1.0]))
    moved = add_noise(form, ball, sample, ball_noise, dt)
    assert not np.allclose(np.asarray(model_inputs(form, ball, moved["u"], moved["v"])[2]), np.asarray(clean[2]))
