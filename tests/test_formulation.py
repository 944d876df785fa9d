"""Targets and update rules (pcmgn_jax.mgn.formulation): true-target round trips for every target type and
formulation, the noise correction landing on the clean frame, the rigid ball."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import DT, make_synthetic_trajectory
from pcmgn_jax.mgn.formulation import (FORMULATIONS, TARGETS, Formulation, add_noise, integrate, is_ball,
                                       previous_displacement, training_sample)


def _roll_back(form: Formulation, traj, dtype=np.float64):
    """Integrate the true targets of every step from frame 0; returns the (T, N, 2) displacements."""
    ball = is_ball(traj.node_type)
    s0 = training_sample(form, ball, points=traj.points, u_prev=previous_displacement(traj.displacement,
                         traj.velocity, 0, DT), u=traj.displacement[0], u_next=traj.displacement[1],
                         vm_next=traj.von_mises[1], dt=DT)
    u, v = s0["u"].astype(dtype), s0["v"].astype(dtype)
    out = [u]
    for t in range(traj.n_frames - 1):
        s = training_sample(form, ball, points=traj.points, u_prev=previous_displacement(traj.displacement,
                            traj.velocity, t, DT), u=traj.displacement[t], u_next=traj.displacement[t + 1],
                            vm_next=traj.von_mises[t + 1], dt=DT)
        u, v = integrate(form, ball, points=jnp.asarray(traj.points, dtype), u=jnp.asarray(u, dtype),
                         v=jnp.asarray(v, dtype), a=jnp.asarray(s["target"][:, :2], dtype),
                         a_ball=jnp.asarray(s["ball"], dtype), dt=DT)
        out.append(np.asarray(u, np.float64))
    return np.stack(out)


@pytest.mark.parametrize("rigid", [False, True])
@pytest.mark.parametrize("target", TARGETS)
def test_true_targets_integrate_back_to_the_trajectory(target, rigid):
    traj = make_synthetic_trajectory(1.0)
    form = Formulation(ball_target=target, panel_target=target, rigid_ball=rigid)
    with jax.enable_x64(True):
        u = _roll_back(form, traj)
    # the synthetic ball moves rigidly, so a rigid ball reproduces it exactly too
    np.testing.assert_allclose(u, traj.displacement, rtol=0, atol=1e-15 if target != "acceleration" else 1e-13)


@pytest.mark.parametrize("name", sorted(FORMULATIONS))
def test_formulations_round_trip_in_float32(name):
    traj = make_synthetic_trajectory(1.2)
    u = _roll_back(FORMULATIONS[name], traj, np.float32)
    scale = np.abs(traj.displacement).max()
    assert np.max(np.abs(u - traj.displacement)) < 2e-5 * scale  # float32 over 11 steps, µm on 0.1 mm


@pytest.mark.parametrize("rigid", [False, True])
@pytest.mark.parametrize("target", TARGETS)
def test_noise_correction_lands_on_the_clean_frame(target, rigid):
    traj = make_synthetic_trajectory(0.9)
    form = Formulation(ball_target=target, panel_target="acceleration" if target == "velocity" else target,
                       rigid_ball=rigid)
    ball = is_ball(traj.node_type)
    t = 5
    s = training_sample(form, ball, points=traj.points, u_prev=traj.displacement[t - 1], u=traj.displacement[t],
                        u_next=traj.displacement[t + 1], vm_next=traj.von_mises[t + 1], dt=DT)
    with jax.enable_x64(True):
        s = {k: jnp.asarray(v) for k, v in s.items()}
        noise = 0.3e-6 * jax.random.normal(jax.random.PRNGKey(0), s["u"].shape, jnp.float64)
        if rigid:
            noise = jnp.where(jnp.asarray(ball)[:, None], noise[np.flatnonzero(ball)[0]][None], noise)
        noisy = add_noise(form, ball, s, noise, DT)
        np.testing.assert_allclose(np.asarray(noisy["v"] - s["v"]), np.asarray(noise) / DT, rtol=1e-9)
        u_next, _ = integrate(form, ball, points=jnp.asarray(traj.points), u=noisy["u"], v=noisy["v"],
                              a=noisy["target"][:, :2], a_ball=noisy["ball"], dt=DT)
    np.testing.assert_allclose(np.asarray(u_next), traj.displacement[t + 1], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(np.asarray(noisy["target"][:, 2]), np.asarray(s["target"][:, 2]))


def test_rigid_ball_inputs_are_rigid_and_formulation_validates():
    traj = make_synthetic_trajectory(1.0)
    ball = is_ball(traj.node_type)
    u = traj.displacement[4].copy()
    u[ball] += np.random.default_rng(0).normal(0, 1e-9, (ball.sum(), 2))  # elastic wiggle of the ball
    s = training_sample(FORMULATIONS["default"], ball, points=traj.points, u_prev=traj.displacement[3], u=u,
                        u_next=traj.displacement[5], vm_next=traj.von_mises[5], dt=DT)
    assert np.ptp(s["u"][ball], axis=0).max() == 0 and np.ptp(s["v"][ball], axis=0).max() == 0
    np.testing.assert_allclose(s["u"][ball][0], u[ball].mean(0))
    with pytest.raises(ValueError, match="ball_target"):
        Formulation(ball_target="jerk")
    with pytest.raises(ValueError, match="normalization"):
        Formulation(normalization="per_node")
