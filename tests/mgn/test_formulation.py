"""Targets and update rules (pcmgn_jax.mgn.formulation): true-target round trips for every target type and
formulation, the noise correction landing on the clean frame, the rigid ball."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fixtures.helpers import DT, make_synthetic_trajectory
from pcmgn_jax.mgn.formulation import (
    FORMULATIONS,
    TARGETS,
    Formulation,
    add_noise,
    integrate,
    is_ball,
    previous_displacement,
    training_sample,
)
from pcmgn_jax.mgn.stress_target import LOG_STRESS_MAX, VM_REF, stress_to_target, target_to_stress


def _sample(form, traj, t):
    ball = is_ball(traj.node_type)
    u_next = traj.displacement[min(t + 1, traj.n_frames - 1)]
    return training_sample(form, ball, points=traj.points, u_prev=previous_displacement(traj.displacement,
                           traj.velocity, t, DT), u=traj.displacement[t], u_next=u_next,
                           vm_next=traj.von_mises[min(t + 1, traj.n_frames - 1)], vm=traj.von_mises[t], dt=DT)


def _roll_back(form: Formulation, traj, dtype=np.float64):
    """Integrate the true targets of every step from frame 0; returns the (T, N, 2) displacements.
    A quasi-static panel's target is its field at the sample's own time: frame t+1 takes the panel rows
    of the sample at t+1 (as a rollout evaluates the panel at the ball's next state)."""
    ball = is_ball(traj.node_type)
    s0 = _sample(form, traj, 0)
    u, v = s0["u"].astype(dtype), s0["v"].astype(dtype)
    out = [u]
    for t in range(traj.n_frames - 1):
        s = _sample(form, traj, t)
        u, v = integrate(form, ball, points=jnp.asarray(traj.points, dtype), u=jnp.asarray(u, dtype),
                         v=jnp.asarray(v, dtype), a=jnp.asarray(s["target"][:, :2], dtype),
                         a_ball=jnp.asarray(s["ball"], dtype), dt=DT)
        if form.panel_model == "quasi_static":
            u = jnp.where(jnp.asarray(ball)[:, None], u,
                          jnp.asarray(_sample(form, traj, t + 1)["target"][:, :2], dtype))
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
        if rigid:  # one shared sample for the rigid ball, which add_noise keeps on the symmetry axis
            noise = jnp.where(jnp.asarray(ball)[:, None], noise[np.flatnonzero(ball)[0]][None], noise)
        noisy = add_noise(form, ball, s, noise, DT)
        seen = jnp.where(jnp.asarray(ball)[:, None], noise * jnp.array([0.0, 1.0]), noise) if rigid else noise
        np.testing.assert_allclose(np.asarray(noisy["v"] - s["v"]), np.asarray(seen) / DT, rtol=1e-9)
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
                        u_next=traj.displacement[5], vm_next=traj.von_mises[5], vm=traj.von_mises[4], dt=DT)
    assert np.ptp(s["u"][ball], axis=0).max() == 0 and np.ptp(s["v"][ball], axis=0).max() == 0
    np.testing.assert_allclose(s["u"][ball][0], [0.0, u[ball].mean(0)[1]])  # rigid, on the symmetry axis
    assert s["ball"][0] == 0.0
    with pytest.raises(ValueError, match="ball_target"):
        Formulation(ball_target="jerk")
    with pytest.raises(ValueError, match="normalization"):
        Formulation(normalization="per_node")


def test_quasi_static_inputs_are_a_function_of_the_ball_state_alone():
    """A quasi-static panel: the graph the network sees does not change with the layers' state, only
    with the rigid ball's (which every node carries as 4 channels); the dynamic panel's graph does."""
    from pcmgn_jax.mgn import contact as contact_lib
    from pcmgn_jax.mgn.formulation import BALL_STATE_CHANNELS, model_inputs
    from pcmgn_jax.mgn.inputs import topology_from_trajectory
    from pcmgn_jax.mgn.rollout import input_graph

    traj = make_synthetic_trajectory(1.0)
    ball = is_ball(traj.node_type)
    topo = topology_from_trajectory(traj)
    index = contact_lib.allocate(points=traj.points, cells=traj.cells, cell_part=traj.cell_part, radius=60e-6,
                                 capacity=256)
    u, v = traj.displacement[6], traj.velocity[6]
    u2 = np.where(ball[:, None], u, u + 3e-6)  # the layers elsewhere, the ball where it is
    v2 = np.where(ball[:, None], v, -v + 0.1)
    qs, dyn = FORMULATIONS["default"], FORMULATIONS["dynamic"]
    assert qs.panel_model == "quasi_static" and qs.node_extra == BALL_STATE_CHANNELS
    g1, _ = input_graph(qs, topo, index, traj.points, u, v)
    g2, _ = input_graph(qs, topo, index, traj.points, u2, v2)
    np.testing.assert_array_equal(np.asarray(g1.nodes), np.asarray(g2.nodes))
    for k in ("mesh", "contact"):
        np.testing.assert_array_equal(np.asarray(g1.edges[k].features), np.asarray(g2.edges[k].features))
    u_in, v_in, extra = model_inputs(qs, ball, u, v)
    np.testing.assert_array_equal(u_in[~ball], 0.0)
    np.testing.assert_array_equal(u_in[ball], u[ball])
    np.testing.assert_allclose(extra, np.broadcast_to(np.r_[u[ball, 1].mean(), v[ball, 1].mean()], extra.shape))
    np.testing.assert_allclose(np.asarray(g1.nodes[:, -BALL_STATE_CHANNELS:]), extra, rtol=1e-6)
    # moving the ball changes the graph; the dynamic panel sees its own state
    g3, _ = input_graph(qs, topo, index, traj.points, np.where(ball[:, None], u - 1e-6, u), v)
    assert not np.array_equal(np.asarray(g3.nodes), np.asarray(g1.nodes))
    d1, _ = input_graph(dyn, topo, index, traj.points, u, v)
    d2, _ = input_graph(dyn, topo, index, traj.points, u2, v2)
    assert not np.array_equal(np.asarray(d1.nodes), np.asarray(d2.nodes))
    with pytest.raises(ValueError, match="quasi_static"):
        Formulation(panel_model="quasi_static")  # a velocity target cannot be a map of the ball's state


def test_layer_thickness_scene_feature_follows_the_design_with_its_derivative():
    """``layer_thickness``: one channel per layer [m] in the scene's order; with ``design`` the design
    layers' entries are the (traced) design, so the optimiser's tangent flows through them."""
    from pcmgn_jax.mgn.scene_features import scene_feature_values
    from pcmgn_jax.scene import default_scene
    scene = default_scene().with_design(80e-6, 120e-6).to_dict()
    names = [layer["name"] for layer in scene["layers"]]
    vals = scene_feature_values(scene, ("ball_radius", "layer_thickness"))
    assert vals.dtype == np.float32 and vals.shape == (1 + len(names),)
    np.testing.assert_allclose(vals[1 + names.index("OCA1")], 80e-6, rtol=1e-6)
    np.testing.assert_allclose(vals[1 + names.index("OCA2")], 120e-6, rtol=1e-6)
    np.testing.assert_allclose(vals[0], scene["ball"]["radius"], rtol=1e-6)
    d = jnp.asarray([60e-6, 140e-6], jnp.float32)
    traced = scene_feature_values(scene, ("layer_thickness",), design=d)
    np.testing.assert_allclose(np.asarray(traced)[[names.index("OCA1"), names.index("OCA2")]], [60e-6, 140e-6])
    np.testing.assert_allclose(np.delete(np.asarray(traced), [names.index("OCA1"), names.index("OCA2")]),
                               np.delete(np.asarray(vals[1:]), [names.index("OCA1"), names.index("OCA2")]))
    jac = np.asarray(jax.jacfwd(lambda x: scene_feature_values(scene, ("layer_thickness",), design=x))(d))
    expect = np.zeros((len(names), 2))
    expect[names.index("OCA1"), 0] = expect[names.index("OCA2"), 1] = 1.0
    np.testing.assert_array_equal(jac, expect)
    assert FORMULATIONS["default"].scene_features == ("layer_thickness",)
    with pytest.raises(ValueError, match="scene feature 'layer_thickness': the scene has no layers.thickness"):
        scene_feature_values({"ball": {}}, ("layer_thickness",))


def test_scene_feature_rows_hide_the_design_from_the_ball():
    """Layer-only features are 0 on the contact pair's nodes (ball, cover glass: they learn the contact
    from the contact); the ball radius reaches every node."""
    from pcmgn_jax.mgn.scene_features import scene_feature_rows, scene_feature_values
    from pcmgn_jax.scene import default_scene
    scene = default_scene().to_dict()
    node_type = np.array([0, 0, 1, 3, 6])
    rows = scene_feature_rows(scene, ("ball_radius", "layer_thickness"), node_type)
    vals = scene_feature_values(scene, ("ball_radius", "layer_thickness"))
    assert rows.shape == (5, len(vals)) and rows.dtype == np.float32
    np.testing.assert_array_equal(rows[3:], np.broadcast_to(vals, (2, len(vals))))  # OCA2, fixed nodes
    np.testing.assert_array_equal(rows[:3, 0], [vals[0]] * 3)   # the radius reaches every node
    assert np.all(rows[:3, 1:] == 0)                            # ball and cover glass: the contact pair
    traced = scene_feature_rows(scene, ("layer_thickness",), node_type, design=jnp.asarray([70e-6, 90e-6]))
    assert np.all(np.asarray(traced)[:3] == 0) and np.asarray(traced)[3, 1] == pytest.approx(70e-6)


_NEW_FIELD = '''
import dataclasses, json, pathlib, tempfile
import pcmgn_jax.mgn.formulation as fm

@dataclasses.dataclass(frozen=True)
class Formulation(fm.Formulation):
    stress_floor: float = 0.0   # a newcomer's new field: a floor under the stress target [Pa]

# the one edit a new field needs, made here by patching the module before anything else imports it
fm.Formulation = Formulation
fm.FORMULATIONS = {k: Formulation(**{f.name: getattr(v, f.name) for f in dataclasses.fields(v)})
                   for k, v in fm.FORMULATIONS.items()}
from pcmgn_jax import cli
from pcmgn_jax.config import TrainConfig
cfg = cli.parse_config(["--preset", "tiny", "--stress_floor=2.5"])
d = pathlib.Path(tempfile.mkdtemp())
cfg.save_json(d / "config.json")
saved = json.loads((d / "config.json").read_text())["formulation"]["stress_floor"]
print(json.dumps([cfg.formulation.stress_floor, saved, TrainConfig.load(d / "config.json") == cfg,
                  cli.parse_config(["--preset", "tiny"]).formulation.stress_floor]))
try:
    cli.parse_train(["--help"], prog="train")
except SystemExit:
    pass
'''


def test_a_new_formulation_field_touches_formulation_py_only(tmp_path):
    """docs/design.md "Where to change what": a field added to ``Formulation`` (and nothing else) is a flag, a
    config.json key that round-trips, a default, and a line of --help, in a fresh interpreter."""
    import json
    import os
    import subprocess
    import sys
    script = tmp_path / "new_field.py"   # a file, so --help can read the field's comment from its source
    script.write_text(_NEW_FIELD)
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "COLUMNS": "250"}, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    first, *rest = run.stdout.splitlines()
    assert json.loads(first) == [2.5, 2.5, True, 0.0]
    assert "--stress_floor" in "\n".join(rest) and "a floor under the stress target" in "\n".join(rest)


VM_PA = np.concatenate([[0.0, 1e-3, 1.0], np.logspace(2, 9, 29)])   # 0 to 1 GPa


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_log_stress_target_round_trips_from_0_to_1_gpa(dtype):
    """stress_target='log': s = log1p(vm / 1 MPa) and back, NumPy and JAX, float32 and float64; 'linear' is vm
    itself (the same array) and max(s, 0) back (the rollout's arithmetic before the option)."""
    vm = VM_PA.astype(dtype)
    rtol = 2e-6 if dtype == np.float32 else 1e-12
    s = stress_to_target("log", vm)
    assert s.dtype == dtype and s[0] == 0 and s[-1] < 7.0
    # the 1 MPa OLED and the 100 MPa cover glass are O(1)
    np.testing.assert_allclose(stress_to_target("log", np.array([1e6, 1e8])), [np.log(2), np.log(101)], rtol=1e-12)
    np.testing.assert_allclose(s, np.log1p(VM_PA / VM_REF), rtol=rtol)
    np.testing.assert_allclose(target_to_stress("log", s), vm, rtol=rtol, atol=1e-12)
    with jax.enable_x64(dtype == np.float64):
        sj = stress_to_target("log", jnp.asarray(vm))
        back = target_to_stress("log", sj)
        assert sj.dtype == back.dtype == dtype
        np.testing.assert_allclose(np.asarray(back), vm, rtol=4 * rtol, atol=1e-12)
    assert stress_to_target("linear", vm) is vm
    out = jnp.asarray(np.array([-6e6, 0.0, 3e5], np.float32))
    np.testing.assert_array_equal(np.asarray(target_to_stress("linear", out)), np.asarray(jnp.maximum(out, 0.0)))
    with pytest.raises(ValueError, match="stress_target must be one of"):
        stress_to_target("sqrt", vm)
    with pytest.raises(ValueError, match="stress_target"):
        Formulation(stress_target="sqrt")


def test_log_stress_decoding_is_clipped_and_its_gradients_finite():
    """A prediction decodes to >= 0 Pa and at most VM_REF expm1(LOG_STRESS_MAX) (an s of 100 would overflow float32);
    the transforms' gradients are finite at vm = 0 and for any output."""
    s = jnp.asarray([-3.0, 0.0, 1.0, 100.0, 1e4], jnp.float32)
    vm = target_to_stress("log", s)
    assert np.all(np.isfinite(np.asarray(vm))) and float(vm[0]) == 0.0 and float(vm[1]) == 0.0
    assert float(vm[-1]) == pytest.approx(VM_REF * np.expm1(LOG_STRESS_MAX), rel=1e-6) and float(vm[-1]) < 1.1e12
    g = jax.grad(lambda x: jnp.sum(target_to_stress("log", x) / VM_REF))(s)
    assert np.all(np.isfinite(np.asarray(g)))
    np.testing.assert_allclose(float(g[2]), np.e, rtol=1e-6)   # d/ds expm1(s) = exp(s)
    zero = jnp.zeros(3, jnp.float32)
    for f in (lambda v: stress_to_target("log", v), lambda v: target_to_stress("log", stress_to_target("log", v))):
        g0 = jax.grad(lambda v: jnp.sum(f(v)))(zero)
        assert np.all(np.isfinite(np.asarray(g0)))
    np.testing.assert_allclose(np.asarray(jax.grad(lambda v: jnp.sum(stress_to_target("log", v)))(zero)), 1 / VM_REF)


@pytest.mark.parametrize("name", ["dynamic", "default"])
def test_training_sample_with_a_log_stress_target(name):
    """The stress target is log1p(vm / 1 MPa) of the stress the formulation's panel predicts (the next frame's, or a
    quasi-static panel's own time); the motion targets and the 'linear' default (vm itself, bit for bit) unchanged."""
    traj = make_synthetic_trajectory(1.0)
    t = 5
    lin = _sample(FORMULATIONS[name], traj, t)
    log = _sample(FORMULATIONS[name].replace(stress_target="log"), traj, t)
    vm = traj.von_mises[t + 1] if name == "dynamic" else traj.von_mises[t]
    assert FORMULATIONS[name].stress_target == "linear" and np.ptp(vm) > 0
    np.testing.assert_array_equal(lin["target"][:, 2], np.asarray(vm, np.float64))
    np.testing.assert_allclose(log["target"][:, 2], np.log1p(np.asarray(vm, np.float64) / 1e6), rtol=1e-15)
    np.testing.assert_array_equal(log["target"][:, :2], lin["target"][:, :2])
    np.testing.assert_array_equal(log["ball"], lin["ball"])
