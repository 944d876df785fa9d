"""Tests for pcmgn_jax.train.noise: drawn statistics and the target correction for each target type."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pcmgn_jax.train.noise import add_position_noise, correct_target, noise_node_mask, sample_position_noise

N_BALL, N_PANEL = 4000, 6000
SIGMA = 0.3e-6
DT = 4e-6


def _mesh():
    node_part = np.concatenate([np.zeros(N_BALL, np.int32), np.repeat(np.arange(1, 7), N_PANEL // 6)])
    fixed = np.zeros(node_part.shape, bool)
    fixed[-500:] = True  # plate bottom
    rng = np.random.default_rng(0)
    pos = np.stack([rng.uniform(0, 5e-3, node_part.size), rng.uniform(-1.5e-3, 10e-3, node_part.size)], 1)
    return node_part, fixed, pos.astype(np.float32)


@pytest.mark.parametrize("parts", ["none", "ball", "panel", "all"])
def test_noise_statistics_and_zero_elsewhere(parts):
    node_part, fixed, pos = _mesh()
    out = jax.jit(lambda k, p: add_position_noise(k, p, node_part, sigma=SIGMA, parts=parts,
                                                  fixed_mask=fixed))(jax.random.PRNGKey(1), pos)
    noise = np.asarray(out.noise, np.float64)
    sel = {"none": np.zeros_like(fixed), "ball": node_part == 0, "panel": node_part != 0,
           "all": np.ones_like(fixed)}[parts] & ~fixed
    assert np.all(noise[~sel] == 0.0)  # exactly zero on other parts and on fixed nodes
    assert np.all(np.asarray(out.positions)[~sel] == pos[~sel])
    if sel.any():
        v = noise[sel].ravel()
        n = v.size
        assert abs(v.mean()) < 4 * SIGMA / np.sqrt(n)
        assert abs(v.std() / SIGMA - 1) < 4 / np.sqrt(2 * n)
        # both components, independent
        assert abs(np.corrcoef(noise[sel, 0], noise[sel, 1])[0, 1]) < 4 / np.sqrt(sel.sum())
        np.testing.assert_allclose(np.asarray(out.positions, np.float64)[sel] - pos[sel], noise[sel],
                                   atol=5e-10)  # float32 half-ulp at 1e-2 m


def test_fixed_nodes_never_noised_and_velocity_unchanged():
    node_part, fixed, pos = _mesh()
    vel = np.ones_like(pos)
    out = add_position_noise(jax.random.PRNGKey(0), pos, node_part, velocity=vel, parts="all",
                             fixed_mask=fixed)
    assert np.all(np.asarray(out.noise)[fixed] == 0)
    assert out.velocity is vel
    assert noise_node_mask(node_part, "ball").sum() == N_BALL
    with pytest.raises(ValueError):
        noise_node_mask(node_part, "oca")


def test_keys_give_different_noise_and_same_key_reproduces():
    node_part, fixed, _ = _mesh()
    a = sample_position_noise(jax.random.PRNGKey(0), node_part)
    b = sample_position_noise(jax.random.PRNGKey(0), node_part)
    c = sample_position_noise(jax.random.PRNGKey(1), node_part)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


@pytest.mark.parametrize("target_type", ["velocity", "displacement", "position"])
def test_correction_lands_on_clean_next_position(target_type):
    """Update rule on the noisy input with the corrected target reproduces x_{t+1} (float64 reference)."""
    rng = np.random.default_rng(3)
    node_part, fixed, _ = _mesh()
    x_t = np.stack([rng.uniform(0, 5e-3, node_part.size), rng.uniform(0, 2e-3, node_part.size)], 1)
    x_t1 = x_t + rng.normal(0, 2e-6, x_t.shape)
    with jax.enable_x64(True):
        out = add_position_noise(jax.random.PRNGKey(2), jnp.asarray(x_t), node_part, parts="all",
                                 fixed_mask=fixed)
        noisy = np.asarray(out.positions)
        target = {"velocity": (x_t1 - x_t) / DT, "displacement": x_t1 - x_t, "position": x_t1}[target_type]
        corr = np.asarray(correct_target(jnp.asarray(target), out.noise, target_type, dt=DT))
    update = {"velocity": lambda t: noisy + t * DT, "displacement": lambda t: noisy + t,
              "position": lambda t: t}[target_type]
    np.testing.assert_allclose(update(corr), x_t1, rtol=0, atol=1e-18)
    if target_type != "position":
        # the uncorrected target misses by the noise
        assert np.abs(update(target) - x_t1).max() > 0.5e-6
    else:
        assert np.array_equal(corr, target)


def test_correction_float32_and_jit():
    rng = np.random.default_rng(4)
    node_part, fixed, _ = _mesh()
    x_t = np.stack([rng.uniform(0, 5e-3, node_part.size), rng.uniform(0, 2e-3, node_part.size)], 1)
    x_t1 = x_t + rng.normal(0, 2e-6, x_t.shape)
    v = ((x_t1 - x_t) / DT).astype(np.float32)

    @jax.jit
    def step(key, x, v):
        out = add_position_noise(key, x, node_part, parts="all", fixed_mask=fixed)
        return out.positions, correct_target(v, out.noise, "velocity", dt=DT)

    noisy, corr = step(jax.random.PRNGKey(5), x_t.astype(np.float32), v)
    err = np.abs(np.asarray(noisy, np.float64) + np.asarray(corr, np.float64) * DT - x_t1)
    assert err.max() < 1e-9  # float32 rounding of mm coordinates (~2e-10 m) only
    with pytest.raises(ValueError):
        correct_target(v, v, "velocity")
    with pytest.raises(ValueError):
        correct_target(v, v, "stress")
