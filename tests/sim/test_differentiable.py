"""The differentiable solver (pcmgn_jax.sim.differentiable): its jax preparation equals the host's, its value
equals the host solver's at the same step, and its reverse-mode gradient equals central finite differences
of itself (the solver at fixed dt) on the tiny mesh, every parameter kind (thickness, modulus, ball radius
and speed). float64 throughout (jax.enable_x64 scoped to each test)."""
from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from fixtures.helpers import CompileCounter
from pcmgn_jax import metrics
from pcmgn_jax.scene import Scene
from pcmgn_jax.sim import differentiable as dsim
from pcmgn_jax.sim.integrate import _device_arrays
from pcmgn_jax.sim.output import to_trajectories
from pcmgn_jax.sim.prepare import SolverSettings
from pcmgn_jax.sim.solver import Calls, simulate

N_FRAMES = 8      # 32 us: the ball touches at ~16 us, so contact is in the window
NAMES = ("OCA1.thickness", "OCA2.thickness", "CG.youngs", "OCA1.youngs", "ball.radius", "ball.velocity")


def _scene(t1=120e-6, t2=80e-6, analysis="axisymmetric"):
    return dataclasses.replace(Scene(analysis=analysis).with_design(t1, t2), n_frames=N_FRAMES)


@pytest.fixture(scope="module")
def tiny():
    with jax.enable_x64(True):
        gs = dsim.setup([_scene()], "tiny", names=NAMES)
        value = dsim.value_fn(gs)
        grad = dsim.value_and_grad_fn(gs)
        v, g = grad(gs.theta)
        yield gs, value, grad, np.asarray(v), np.asarray(g)


def test_jax_preparation_equals_host(tiny):
    """Stencil coefficients, masses, penalties, stress operator and initial velocity from the jax functions
    of the parameters equal the host's NumPy preparation (one element definition)."""
    gs, *_ = tiny
    scene = _scene()
    with jax.enable_x64(True):
        arrays, _, v0, dt = jax.jit(lambda t: dsim.solver_inputs(gs, t))(gs.theta)
        settings = SolverSettings(dtype="float64")
        from pcmgn_jax.sim.prepare import prepare
        prep = prepare([scene], "tiny", settings)
        calls = Calls([scene], prep, settings=settings, n_frames=N_FRAMES, output_dt=scene.output_dt)
        host, layout = _device_arrays(
            points=prep.points, cells=prep.mesh.cells, ke=prep.ke, db=prep.db, mass=prep.mass, free=prep.free,
            ball_weight=calls.ball_w, slaves=prep.slaves, masters=prep.masters, k_slave=prep.k_slave,
            node_slots=prep.node_slots, avg_weight=prep.avg_weight, shared_rows=np.zeros(prep.mesh.n_nodes, bool),
            dtype="float64")
    assert layout == gs.layout and float(dt[0]) == calls.dt and calls.n_sub == gs.n_sub
    for key in ("mass", "ball_weight", "contact_scale", "points", "k_slave", "db"):
        np.testing.assert_allclose(np.asarray(arrays[key]), np.asarray(host[key]), rtol=1e-12,
                                   atol=1e-14 * np.abs(np.asarray(host[key])).max(), err_msg=key)
    for a, b in zip(arrays["stencil"]["blocks"] + [arrays["stencil"]["rem_blocks"]],
                    host["stencil"]["blocks"] + [host["stencil"]["rem_blocks"]]):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=1e-12 * np.abs(np.asarray(b)).max())
    np.testing.assert_array_equal(np.asarray(v0), calls.v0)


@pytest.mark.slow
def test_value_equals_host_solver(tiny):
    """At the batch's own step the differentiable objective is the host solver's (float64 both)."""
    gs, value, _, v, _ = tiny
    scene = _scene()
    with jax.enable_x64(True):
        settings = SolverSettings(dtype="float64")
        res = simulate([scene], "tiny", settings=settings)
        traj = to_trajectories(res, [scene], "tiny", settings=settings)[0]
    host = metrics.oled_objective_of(traj) * 1e6
    assert res.dt == gs.dt
    np.testing.assert_allclose(v[0], host, rtol=1e-10)
    np.testing.assert_allclose(np.asarray(value(gs.theta))[0], host, rtol=1e-10)


def test_gradient_matches_central_differences(tiny):
    """Every parameter within 1 % of the scaled gradient's norm (the components theta_k df/dtheta_k [Pa]) of a
    central difference at a relative step of 1e-4 (the step study is in experiments.gradient --fd)."""
    gs, value, _, v, g = tiny
    theta = gs.theta[0]
    rel = 1e-4
    with jax.enable_x64(True):
        probes = []
        for k in range(len(theta)):
            for sign in (1, -1):
                t = theta.copy()
                t[k] += sign * rel * abs(theta[k])
                probes.append(t)
        f = np.asarray(jax.vmap(lambda t: value(t[None])[0])(np.stack(probes)))
    fd = (f[0::2] - f[1::2]) / (2 * rel * np.abs(theta))
    scaled_g, scaled_fd = g[0] * theta, fd * theta
    err = np.abs(scaled_g - scaled_fd) / np.linalg.norm(scaled_g)
    assert np.all(np.isfinite(g)) and np.all(scaled_g != 0)
    assert err.max() < 0.01, dict(zip(gs.pmap.names, err))


def test_no_recompilation_for_new_parameters(tiny):
    gs, value, grad, *_ = tiny
    with jax.enable_x64(True), CompileCounter("run") as c:
        grad(gs.theta * 1.01)
        value(gs.theta * 0.99)
    assert c.count == 0


@pytest.mark.slow
@pytest.mark.parametrize("reading", ["peak", "node_mean", "disc_mean"])
def test_other_readings_have_finite_gradients(reading):
    """The peak (through its argmax), the node mean (fixed weights) and the disc mean (weights through the
    mesh) give finite gradients; plane strain too."""
    with jax.enable_x64(True):
        gs = dsim.setup([dataclasses.replace(_scene(analysis="plane_strain" if reading == "peak" else
                                                    "axisymmetric"), n_frames=6)],
                        "tiny", names=("OCA1.thickness", "CG.youngs", "ball.velocity"), reading=reading)
        v, g = dsim.value_and_grad_fn(gs)(gs.theta)
    assert np.isfinite(np.asarray(v)).all() and np.isfinite(np.asarray(g)).all() and np.any(np.asarray(g) != 0)
