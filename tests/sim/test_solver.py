"""Explicit solver: wave speeds, energy balance, instability detection, float32 vs float64,
batching and compilation. Runs on the ``tiny`` preset and on hand-built bars (fast)."""
from __future__ import annotations

import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pcmgn_jax.scene import default_scene
from pcmgn_jax.sim import fem, solver
from pcmgn_jax.sim.solver import SolverError, SolverSettings, simulate

VECTORISED = SolverSettings(designs_per_call=2)  # both designs in one compiled call
N_FRAMES = 12  # 48 us: the ball touches at ~16 us, so 32 us of contact
S1 = default_scene(t_oca1=50e-6, t_oca2=50e-6)
S2 = default_scene(t_oca1=150e-6, t_oca2=150e-6)
S3 = default_scene(t_oca1=80e-6, t_oca2=120e-6)


# ---- wave speeds through the solver's own integrator (solver._run) on a bar -------------------
STEEL = (200e9, 0.3, 7850.0)


def _bar(n_long, n_wide, h, analysis, constrained, r0=0.0):
    """A bar along y of n_long x n_wide square elements of size h [m]. ``constrained``: lateral
    dofs fixed (uniaxial strain); otherwise lateral faces free (axis fixed in x if axisymmetric)."""
    xs = r0 + h * np.arange(n_wide + 1)
    ys = h * np.arange(n_long + 1)
    X, Y = np.meshgrid(xs, ys, indexing="xy")
    pts = np.stack([X.ravel(), Y.ravel()], 1)
    idx = np.arange(len(pts)).reshape(n_long + 1, n_wide + 1)
    cells = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    free = np.ones((len(pts), 2))
    if constrained:
        free[:, 0] = 0.0
    elif analysis == "axisymmetric":
        free[pts[:, 0] == 0.0, 0] = 0.0
    return pts, cells, idx, free


def _run_bar(analysis, constrained, speed, n_long=400, n_wide=2, h=10e-6, r0=0.0, frames=3):
    """Launch a right-moving Gaussian pulse u_y = f(y - c t) and return the speed [m/s] of its
    peak measured over ``frames`` output frames, and the run's energies."""
    youngs, nu, rho = STEEL
    pts, cells, idx, free = _bar(n_long, n_wide, h, analysis, constrained, r0)
    n = len(pts)
    ne = len(cells)
    ke, me, db = fem.element_matrices(pts, cells, np.full(ne, youngs), np.full(ne, nu),
                                      np.full(ne, rho), analysis=analysis)
    mass = np.zeros(n)
    np.add.at(mass, cells, me)
    slots, avg_w = solver._node_slots(cells, n, np.zeros(ne, int), np.zeros(n, int))
    # stable step from the largest eigenvalue of M^-1 K on the free dofs, as in solver.prepare
    fd = np.flatnonzero(free.ravel() > 0)
    w2 = solver._largest_omega2(fem.assemble_csr(cells, ke, n), 1.0 / np.sqrt(np.repeat(mass, 2)[fd]), fd)
    dt = 0.9 * 2.0 / math.sqrt(w2)
    length = n_long * h
    y0, width = 0.25 * length, 15 * h
    total = 0.45 * length / speed
    n_sub = int(math.ceil(total / frames / dt))
    dt = total / frames / n_sub
    f = 1e-6 * np.exp(-(((pts[:, 1] - y0) / width) ** 2))
    u0 = np.zeros((n, 2))
    v0 = np.zeros((n, 2))
    u0[:, 1] = f
    v0[:, 1] = speed * 2 * (pts[:, 1] - y0) / width**2 * f  # -c df/dy: moves towards +y
    u0 *= free
    v0 *= free
    arrays, layout = solver._device_arrays(
        points=pts[None], cells=cells, ke=ke[None], db=db[None], mass=mass[None], free=free,
        ball_weight=np.zeros((1, n)), node_slots=slots, avg_weight=avg_w,
        # no contact: one slave over a two-node master segment with zero stiffness
        slaves=np.array([idx[-1, 0]]), masters=idx[0, :2], k_slave=np.zeros((1, 1)),
        shared_rows=np.ones(n, bool), dtype=jnp.float32)

    def node_major(x):  # (N,2) -> (2,1,N)
        return jnp.asarray(x.T[:, None, :], jnp.float32)
    us, _, _, es, _ = solver._run(arrays, node_major(u0), node_major(v0), jnp.full((1,), dt, jnp.float32),
                                  layout=layout, n_frames=frames, n_sub=n_sub,
                                  rigid_x=analysis == "plane_strain")
    us, es = us[0], es[0]
    col = np.asarray(us, np.float64)[:, idx[:, 0], 1]  # (frames+1, n_long+1) along the axis column
    peaks = []
    for c in col:
        i = int(np.argmax(c))
        a, b, cc = c[i - 1], c[i], c[i + 1]
        peaks.append((i + 0.5 * (a - cc) / (a - 2 * b + cc)) * h)
    t = np.arange(frames + 1) * n_sub * dt
    measured = np.polyfit(t, peaks, 1)[0]
    return measured, np.asarray(es, np.float64), col


def _c_dilatational(youngs, nu, rho):
    return math.sqrt(youngs * (1 - nu) / (rho * (1 + nu) * (1 - 2 * nu)))


@pytest.mark.parametrize("analysis", ["plane_strain", "axisymmetric"])
def test_dilatational_wave_speed(analysis):
    """Laterally constrained bar (uniaxial strain): the pulse travels at c_d."""
    c_d = _c_dilatational(*STEEL)
    measured, energy, col = _run_bar(analysis, True, c_d, r0=1e-3 if analysis == "axisymmetric" else 0.0)
    err = measured / c_d - 1
    print(f"{analysis}: c_d = {c_d:.1f} m/s, measured {measured:.1f} m/s, error {err:.2e}")
    assert abs(err) < 0.02
    assert abs(err) < 2e-3  # what the 20-elements-per-pulse discretisation actually gives
    # non-dispersive, no reflection yet: the pulse keeps its amplitude, energy is conserved
    assert col[-1].max() == pytest.approx(col[0].max(), rel=5e-3)
    total = energy.sum(axis=1)
    assert np.abs(total - total[0]).max() < 1e-4 * total[0]


@pytest.mark.parametrize("analysis,expected", [
    ("plane_strain", math.sqrt(STEEL[0] / ((1 - STEEL[1] ** 2) * STEEL[2]))),  # plane-strain plate
    ("axisymmetric", math.sqrt(STEEL[0] / STEEL[2])),  # slender rod: the bar speed sqrt(E/rho)
], ids=["plane_strain", "axisymmetric"])
def test_bar_wave_speed(analysis, expected):
    """Free lateral faces, width << pulse length: the bar speed, 10-16 % below c_d; the
    axisymmetric rod needs the hoop term to contract laterally (sqrt(E/rho))."""
    measured, _, _ = _run_bar(analysis, False, expected)
    err = measured / expected - 1
    print(f"{analysis} bar: expected {expected:.1f} m/s, measured {measured:.1f} m/s, error {err:.2e}")
    assert abs(err) < 0.02
    assert abs(measured / _c_dilatational(*STEEL) - 1) > 0.08  # and clearly not c_d


# ---- the tiny panel scene -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def runs():
    out = {"s1": simulate([S1], "tiny", n_frames=N_FRAMES),
           "s2": simulate([S2], "tiny", n_frames=N_FRAMES),
           "batch": simulate([S1, S2], "tiny", n_frames=N_FRAMES),
           "batch_vectorised": simulate([S1, S2], "tiny", n_frames=N_FRAMES, settings=VECTORISED)}
    with jax.enable_x64(True):
        out["f64"] = simulate([S1], "tiny", n_frames=N_FRAMES, settings=SolverSettings(dtype="float64"))
    return out


def test_result_shapes_and_contact(runs):
    r = runs["s1"]
    n = r.prepared.mesh.n_nodes
    assert r.u.shape == (1, N_FRAMES + 1, n, 2) and r.v.shape == r.u.shape
    assert r.von_mises.shape == (1, N_FRAMES + 1, n) and r.energy.shape == (1, N_FRAMES + 1, 3)
    assert r.force.shape == (1, N_FRAMES, r.n_sub) and r.approach.shape == r.force.shape
    assert r.n_sub * r.dt == pytest.approx(S1.output_dt, rel=1e-12)
    assert r.dt <= r.prepared.dt_stable * (1 + 1e-12)
    # free flight until the 10 um gap closes at v0: no force, ball moves rigidly at -v0
    t_touch = S1.ball.gap / S1.ball.velocity
    t = (np.arange(r.force[0].size) + 1) * r.dt
    f = r.force[0].ravel()
    assert np.all(f[t < 0.98 * t_touch] == 0.0)
    assert f[t > 1.05 * t_touch].min() > 0 and f.max() > 1.0
    approach = r.approach[0].ravel()
    free_flight = t < 0.98 * t_touch
    np.testing.assert_allclose(approach[free_flight], -S1.ball.velocity * (t[free_flight] - r.dt),
                               rtol=1e-4, atol=1e-12)
    # kinetic energy of the whole sphere (axisymmetric ring masses), within the polygon error
    ke0 = 0.5 * S1.ball.mass_full * S1.ball.velocity**2
    assert r.energy[0, 0, 0] == pytest.approx(ke0, rel=0.02)
    # supports hold
    fixed = r.prepared.mesh.fixed
    assert np.all(r.u[0][:, fixed] == 0.0) and np.all(r.v[0][:, fixed] == 0.0)
    assert np.isfinite(r.von_mises).all() and r.von_mises.min() >= 0


def test_energy_conservation_tiny():
    """Through contact onset and loading (100 us): |E(t) - E(0)| < 1 % of the initial KE."""
    r = simulate([S1], "tiny", n_frames=25)
    e = r.energy[0]
    err = np.abs(e.sum(1) - e[0].sum()) / e[0, 0]
    print(f"tiny, 25 frames: max energy error {err.max():.2e}; KE {e[-1, 0] / e[0, 0]:.3f} of initial")
    assert r.energy_error[0] == pytest.approx(err.max(), rel=1e-6)
    assert r.energy_error[0] < 0.01
    assert r.energy_error[0] < 1e-3  # actual: ~4e-5
    assert e[-1, 0] < 0.5 * e[0, 0] and e[-1, 1] > 0.3 * e[0, 0]  # energy really went into the panel


def test_stable_step_bounds_the_coupled_eigenvalue(runs):
    """dt comes from Weyl's bound mesh + Gershgorin(contact) (docs/design.md §3), which lies above the
    largest eigenvalue of M^-1 (K + K_contact) with every spring engaged, itself above the mesh's."""
    p = runs["batch"].prepared
    assert np.all(p.omega2_coupled >= p.omega2_mesh * (1 - 1e-3))
    assert np.all(p.omega2_coupled <= (p.omega2_mesh + p.omega2_contact) * (1 + 1e-3))
    assert p.dt_stable == pytest.approx(0.9 * 2.0 / math.sqrt(np.max(p.omega2_mesh + p.omega2_contact)),
                                        rel=1e-12)


def test_unstable_step_raises_naming_the_frame():
    with pytest.raises(SolverError, match=r"frame \d+ \(t = "):
        simulate([S1], "tiny", n_frames=6, settings=SolverSettings(safety=3.0))


def test_energy_tolerance_raises_naming_the_frame(runs):
    with pytest.raises(SolverError, match=r"energy error .* at frame (\d+)") as info:
        simulate([S1], "tiny", n_frames=N_FRAMES, settings=SolverSettings(energy_tol=1e-9))
    frame = int(re.search(r"at frame (\d+)", str(info.value)).group(1))
    assert frame * S1.output_dt >= S1.ball.gap / S1.ball.velocity  # not before the contact


def test_float64_needs_x64_context():
    if jax.config.read("jax_enable_x64"):
        pytest.skip("x64 enabled globally")
    with pytest.raises(ValueError, match="enable_x64"):
        simulate([S1], "tiny", n_frames=1, settings=SolverSettings(dtype="float64"))


def _rel(a, b):
    return float(np.abs(a - b).max() / np.abs(b).max())


def test_float32_matches_float64(runs):
    r32, r64 = runs["s1"], runs["f64"]
    assert r64.n_sub == r32.n_sub
    mesh = r32.prepared.mesh
    du = _rel(r32.u, r64.u)
    oled = mesh.node_part == mesh.part_names.index("OLED")
    d_oled = _rel(r32.von_mises[..., oled], r64.von_mises[..., oled])
    d_vm = _rel(r32.von_mises, r64.von_mises)
    d_f = _rel(r32.force, r64.force)
    print(f"f32 vs f64 (tiny, {N_FRAMES} frames): u {du:.2e}, von Mises all {d_vm:.2e}, "
          f"OLED {d_oled:.2e}, contact force {d_f:.2e}; energy error f32 {r32.energy_error[0]:.1e} "
          f"f64 {r64.energy_error[0]:.1e}")
    assert du < 1e-3
    assert d_oled < 1e-3  # the design objective's part
    assert d_f < 1e-2
    assert r64.energy_error[0] < 1e-6


def test_float32_stress_matches_float64_everywhere(runs):
    """The ball's rigid drop is carried in its own scalar state, so float32 keeps its elastic
    deformation: von Mises everywhere within 1e-3 of the float64 run."""
    assert _rel(runs["s1"].von_mises, runs["f64"].von_mises) < 1e-3


@pytest.mark.parametrize("batch", ["batch", "batch_vectorised"])
def test_batch_equals_single_runs(runs, batch):
    rb = runs[batch]
    for i, key in enumerate(("s1", "s2")):
        r = runs[key]
        assert r.n_sub == rb.n_sub and r.dt == rb.dt
        for name in ("u", "v", "von_mises", "force", "approach"):
            a, b = getattr(rb, name)[i], getattr(r, name)[0]
            assert np.abs(a - b).max() <= 1e-5 * np.abs(b).max(), (key, name)
        np.testing.assert_allclose(rb.energy[i], r.energy[0], rtol=1e-5, atol=1e-9 * r.energy[0, 0, 0])
    # the designs really differ
    assert _rel(rb.von_mises[0], rb.von_mises[1]) > 1e-2


def test_no_recompilation_for_new_design_same_shapes(runs):
    before = solver._run_batch._cache_size()
    assert before >= 1
    r = simulate([S3], "tiny", n_frames=N_FRAMES)
    assert r.n_sub == runs["s1"].n_sub  # same static arguments
    assert solver._run_batch._cache_size() == before
    r = simulate([S2, S3], "tiny", n_frames=N_FRAMES)
    assert solver._run_batch._cache_size() == before
    r = simulate([S2, S3], "tiny", n_frames=N_FRAMES, settings=VECTORISED)
    assert solver._run_batch._cache_size() == before


def test_designs_with_different_topology_rejected():
    from pcmgn_jax.sim.mesh import with_spec
    # a scene whose CG thickness differs is fine (same counts), but a different half width is not
    wide = default_scene(half_width=9e-3)
    with pytest.raises(ValueError, match="topology"):
        solver.prepare([S1, wide], with_spec("tiny"))


def test_each_design_of_a_batch_gets_its_own_contact_penalty():
    """The penalty scales with the softer contact body's modulus: a batch whose second design has a softer
    cover glass must give that design a softer penalty, not the first design's (a batch is not one design)."""
    import dataclasses

    from pcmgn_jax.sim.mesh import with_spec
    soft_cg = dataclasses.replace(S1.layers[0], youngs=S1.layers[0].youngs / 2)
    soft = dataclasses.replace(S1, layers=(soft_cg,) + S1.layers[1:])
    alone = [solver.prepare([s], with_spec("tiny")).k_slave[0] for s in (S1, soft)]
    both = solver.prepare([S1, soft], with_spec("tiny")).k_slave
    np.testing.assert_allclose(both[0], alone[0], rtol=1e-12)
    np.testing.assert_allclose(both[1], alone[1], rtol=1e-12)
    assert np.all(both[1] < both[0])
