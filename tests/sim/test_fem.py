"""Q4 elements: stiffness against scikit-fem, patch tests, rigid modes, mass, von Mises."""
from __future__ import annotations

import numpy as np
import pytest

from pcmgn_jax.sim import fem


def distorted_grid(nx=4, ny=3, lx=2e-3, ly=1e-3, x0=0.0, y0=0.0, amp=0.25, seed=0):
    """Structured nx x ny quad grid [m] with interior nodes moved randomly by up to ``amp``
    element sizes (all quads stay convex). Returns points, CCW cells, boundary mask."""
    rng = np.random.default_rng(seed)
    xs = x0 + np.linspace(0, lx, nx + 1)
    ys = y0 + np.linspace(0, ly, ny + 1)
    X, Y = np.meshgrid(xs, ys, indexing="xy")
    pts = np.stack([X.ravel(), Y.ravel()], 1)
    idx = np.arange(pts.shape[0]).reshape(ny + 1, nx + 1)
    boundary = np.zeros_like(idx, bool)
    boundary[0, :] = boundary[-1, :] = boundary[:, 0] = boundary[:, -1] = True
    boundary = boundary.ravel()
    h = np.array([lx / nx, ly / ny])
    pts[~boundary] += amp * h * rng.uniform(-1, 1, size=(int((~boundary).sum()), 2))
    cells = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    return pts, cells, boundary


def _mats(n_el, youngs=70e9, nu=0.3, rho=2700.0):
    return np.full(n_el, youngs), np.full(n_el, nu), np.full(n_el, rho)


def _polygon_area_and_moment(points, cells):
    """Exact area and first moment int x dA of each straight-edged quad."""
    xy = points[cells]
    x, y = xy[..., 0], xy[..., 1]
    xn, yn = np.roll(x, -1, 1), np.roll(y, -1, 1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum(1)
    mx = (cross * (x + xn)).sum(1) / 6.0
    return area, mx


# ---- against scikit-fem ------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1])
def test_plane_strain_stiffness_matches_scikit_fem(seed):
    """The full-integration element against scikit-fem (the incompatible-mode one: the tests below)."""
    skfem = pytest.importorskip("skfem")
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    pts, cells, _ = distorted_grid(5, 4, seed=seed, amp=0.3)
    youngs, nu = 77e9, 0.21
    ke, _, _ = fem.element_matrices(pts, cells, *_mats(len(cells), youngs, nu), analysis="plane_strain",
                                    element="q4")
    k_ours = fem.assemble_csr(cells, ke, len(pts)).toarray()

    mesh = skfem.MeshQuad(pts.T.copy(), cells.T.copy())
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementQuad1()), intorder=2)
    # scikit-fem interleaves the vector dofs node by node, like fem.assemble_csr
    np.testing.assert_array_equal(basis.nodal_dofs, np.stack([2 * np.arange(len(pts)), 2 * np.arange(len(pts)) + 1]))
    k_sk = skfem.asm(linear_elasticity(*lame_parameters(youngs, nu)), basis).toarray()
    err = np.abs(k_ours - k_sk).max() / np.abs(k_sk).max()
    assert err < 1e-8, err
    # and a general-purpose check independent of the reference: symmetric, 3 rigid modes
    np.testing.assert_allclose(k_ours, k_ours.T, rtol=0, atol=1e-12 * np.abs(k_ours).max())
    ev = np.linalg.eigvalsh(k_ours)
    assert np.sum(ev < 1e-9 * ev.max()) == 3 and ev.min() > -1e-9 * ev.max()


def test_axisymmetric_stiffness_matches_scikit_fem_form():
    """The hoop term against an independent weak form: int (sigma : eps + s_tt e_tt) 2 pi r dA."""
    skfem = pytest.importorskip("skfem")
    from skfem import BilinearForm

    pts, cells, _ = distorted_grid(4, 3, x0=0.0, seed=3, amp=0.3)  # includes the axis r = 0
    youngs, nu = 5.15e9, 0.3
    lam = youngs * nu / ((1 + nu) * (1 - 2 * nu))
    mu = youngs / (2 * (1 + nu))
    ke, _, _ = fem.element_matrices(pts, cells, *_mats(len(cells), youngs, nu), analysis="axisymmetric",
                                    element="q4")
    k_ours = fem.assemble_csr(cells, ke, len(pts)).toarray()

    @BilinearForm
    def axi(u, v, w):
        r = w.x[0]
        gu, gv = u.grad, v.grad
        eu = 0.5 * (gu + np.swapaxes(gu, 0, 1))
        ev = 0.5 * (gv + np.swapaxes(gv, 0, 1))
        hu, hv = u[0] / r, v[0] / r
        tru = eu[0, 0] + eu[1, 1] + hu
        trv = ev[0, 0] + ev[1, 1] + hv
        ddot = sum(eu[i, j] * ev[i, j] for i in range(2) for j in range(2))
        return (lam * tru * trv + 2 * mu * (ddot + hu * hv)) * 2 * np.pi * r

    mesh = skfem.MeshQuad(pts.T.copy(), cells.T.copy())
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementQuad1()), intorder=2)
    k_sk = skfem.asm(axi, basis).toarray()
    err = np.abs(k_ours - k_sk).max() / np.abs(k_sk).max()
    assert err < 1e-8, err
    ev = np.linalg.eigvalsh(k_ours)
    assert np.sum(ev < 1e-9 * ev.max()) == 1  # only the axial translation is rigid


# ---- patch tests ------------------------------------------------------------------------------
def _strain_and_forces(pts, cells, u, analysis, youngs=77e9, nu=0.21, element=fem.DEFAULT_ELEMENT):
    ke, _, db = fem.element_matrices(pts, cells, *_mats(len(cells), youngs, nu), analysis=analysis, element=element)
    k = fem.assemble_csr(cells, ke, len(pts))
    f = (k @ u.ravel()).reshape(-1, 2)
    sig = np.einsum("ekj,ej->ek", db, u[cells].reshape(len(cells), 8))
    d = fem.elasticity_matrix(np.array([youngs]), np.array([nu]))[0]
    return f, sig, d, ke


@pytest.mark.parametrize("element", fem.Q4_ELEMENTS)
@pytest.mark.parametrize("seed", [0, 5])
def test_patch_plane_strain(seed, element):
    pts, cells, boundary = distorted_grid(5, 4, seed=seed, amp=0.3)
    a = np.array([[2.0e-3, -0.7e-3], [1.1e-3, -1.5e-3]])
    b = np.array([3e-6, -2e-6])
    u = pts @ a.T + b
    f, sig, d, ke = _strain_and_forces(pts, cells, u, "plane_strain", element=element)
    scale = np.abs(ke).max() * np.abs(u).max()
    assert np.abs(f[~boundary]).max() < 1e-12 * scale
    assert np.abs(f[boundary]).max() > 1e-3 * scale  # the traction is really there
    eps = np.array([a[0, 0], a[1, 1], a[0, 1] + a[1, 0], 0.0])
    np.testing.assert_allclose(sig, np.broadcast_to(d @ eps, sig.shape), rtol=1e-12, atol=1e-12 * np.abs(d @ eps).max())
    # boundary forces are the tractions of the uniform stress: they sum to zero
    np.testing.assert_allclose(f.sum(0), 0.0, atol=1e-12 * scale)


@pytest.mark.parametrize("element", fem.Q4_ELEMENTS)
@pytest.mark.parametrize("x0", [0.0, 1e-3])  # touching the axis, and off the axis
def test_patch_axisymmetric(x0, element):
    """u_r = a r, u_z = b z + c: uniform strain (a, b, 0, a) incl. the hoop strain; it is in
    equilibrium without body force, so interior nodal forces vanish."""
    pts, cells, boundary = distorted_grid(5, 4, x0=x0, seed=2, amp=0.3)
    aa, bb, cc = 1.7e-3, -0.9e-3, 4e-6
    u = np.stack([aa * pts[:, 0], bb * pts[:, 1] + cc], 1)
    f, sig, d, ke = _strain_and_forces(pts, cells, u, "axisymmetric", element=element)
    scale = np.abs(ke).max() * np.abs(u).max()
    assert np.abs(f[~boundary]).max() < 1e-12 * scale
    eps = np.array([aa, bb, 0.0, aa])
    np.testing.assert_allclose(sig, np.broadcast_to(d @ eps, sig.shape), rtol=1e-12,
                               atol=1e-12 * np.abs(d @ eps).max())
    # axial resultant: the bottom and top faces carry s_zz * pi (r1^2 - r0^2) each, opposite
    top = np.isclose(pts[:, 1], pts[:, 1].max())
    r0, r1 = x0, x0 + 2e-3
    assert f[top, 1].sum() == pytest.approx((d @ eps)[1] * np.pi * (r1**2 - r0**2), rel=1e-10)


@pytest.mark.parametrize("element", fem.Q4_ELEMENTS)
@pytest.mark.parametrize("analysis", ["plane_strain", "axisymmetric"])
def test_rigid_vertical_translation_is_force_free(analysis, element):
    pts, cells, _ = distorted_grid(4, 4, seed=7, amp=0.3)
    u = np.zeros_like(pts)
    u[:, 1] = 1e-5
    f, sig, _, ke = _strain_and_forces(pts, cells, u, analysis, element=element)
    assert np.abs(f).max() < 1e-12 * np.abs(ke).max() * 1e-5
    assert np.abs(sig).max() < 1e-12 * 77e9 * 1e-5 / 1e-3
    if analysis == "plane_strain":  # in-plane rigid rotation too (not rigid in axisymmetry)
        th = 1e-4
        u = th * np.stack([-pts[:, 1], pts[:, 0]], 1)
        f, sig, _, _ = _strain_and_forces(pts, cells, u, analysis, element=element)
        assert np.abs(f).max() < 1e-12 * np.abs(ke).max() * np.abs(u).max()
    else:  # a radial translation stretches the hoops
        u = np.zeros_like(pts)
        u[:, 0] = 1e-5
        f, _, _, _ = _strain_and_forces(pts, cells, u, analysis, element=element)
        assert np.abs(f).max() > 1e-3 * np.abs(ke).max() * 1e-5


# ---- mass -------------------------------------------------------------------------------------
@pytest.mark.parametrize("x0", [0.0, 0.5e-3])
def test_lumped_mass_totals(x0):
    pts, cells, _ = distorted_grid(5, 3, x0=x0, seed=4, amp=0.3)
    rho = np.where(np.arange(len(cells)) % 2 == 0, 2500.0, 7850.0)
    youngs, nu = np.full(len(cells), 1e9), np.full(len(cells), 0.3)
    area, moment = _polygon_area_and_moment(pts, cells)
    _, me, _ = fem.element_matrices(pts, cells, youngs, nu, rho, analysis="plane_strain")
    assert me.sum() == pytest.approx(np.sum(rho * area), rel=1e-12)
    np.testing.assert_allclose(me.sum(1), rho * area, rtol=1e-12)
    assert me.min() > 0
    _, me, _ = fem.element_matrices(pts, cells, youngs, nu, rho, analysis="axisymmetric")
    np.testing.assert_allclose(me.sum(1), rho * 2 * np.pi * moment, rtol=1e-12)
    if x0 == 0.0:
        assert me.min() >= 0  # axis nodes carry (almost) no ring mass but never negative
    else:
        assert me.min() > 0
    # a rectangle ring: rho * pi (r1^2 - r0^2) h
    ring = np.array([[x0, 0], [x0 + 1e-3, 0], [x0 + 1e-3, 2e-4], [x0, 2e-4]])
    _, me, _ = fem.element_matrices(ring, np.array([[0, 1, 2, 3]]), [1e9], [0.3], [1000.0],
                                    analysis="axisymmetric")
    assert me.sum() == pytest.approx(1000.0 * np.pi * ((x0 + 1e-3) ** 2 - x0**2) * 2e-4, rel=1e-12)


# ---- misc ---------------------------------------------------------------------------------------
def test_clockwise_element_rejected():
    pts, cells, _ = distorted_grid(2, 2)
    bad = cells.copy()
    bad[1] = bad[1, ::-1]
    with pytest.raises(ValueError, match="element 1 .*Jacobian"):
        fem.element_matrices(pts, bad, *_mats(len(cells)), analysis="plane_strain")
    with pytest.raises(ValueError, match="analysis"):
        fem.element_matrices(pts, cells, *_mats(len(cells)), analysis="plane_stress")
    with pytest.raises(ValueError, match="element 'c3d8'"):
        fem.element_matrices(pts, cells, *_mats(len(cells)), analysis="plane_strain", element="c3d8")


def test_von_mises():
    s = 123e6
    assert fem.von_mises(np.array([s, 0, 0, 0])) == pytest.approx(s)
    assert fem.von_mises(np.array([0, 0, s, 0])) == pytest.approx(np.sqrt(3) * s)
    assert fem.von_mises(np.array([s, s, 0, s])) == pytest.approx(0.0, abs=1e-6)
    assert fem.von_mises(np.array([s, -s, 0, 0])) == pytest.approx(np.sqrt(3) * s)
    batch = fem.von_mises(np.array([[s, 0, 0, 0], [0, 0, s, 0]]))
    np.testing.assert_allclose(batch, [s, np.sqrt(3) * s])


def test_plane_strain_out_of_plane_stress():
    """eps_zz = 0 but sigma_zz = lambda (eps_xx + eps_yy) enters the von Mises stress."""
    pts, cells, _ = distorted_grid(1, 1, amp=0.0)
    u = np.stack([1e-3 * pts[:, 0], np.zeros(len(pts))], 1)
    youngs, nu = 100e9, 0.25
    _, _, db = fem.element_matrices(pts, cells, *_mats(1, youngs, nu), analysis="plane_strain")
    sig = db[0] @ u[cells[0]].ravel()
    lam = youngs * nu / ((1 + nu) * (1 - 2 * nu))
    mu = youngs / (2 * (1 + nu))
    np.testing.assert_allclose(sig, [(lam + 2 * mu) * 1e-3, lam * 1e-3, 0, lam * 1e-3], rtol=1e-12)


@pytest.mark.parametrize("element", fem.Q4_ELEMENTS)
def test_element_stiffness_invariant_under_rigid_motion_of_mesh(element):
    """Translating the mesh (plane strain) or shifting it along the axis (axisymmetric) does
    not change the element matrices."""
    pts, cells, _ = distorted_grid(3, 2, x0=0.2e-3, seed=9)
    for analysis, shift in (("plane_strain", [5e-3, -2e-3]), ("axisymmetric", [0.0, 7e-3])):
        k1, m1, d1 = fem.element_matrices(pts, cells, *_mats(len(cells)), analysis=analysis, element=element)
        k2, m2, d2 = fem.element_matrices(pts + np.array(shift), cells, *_mats(len(cells)), analysis=analysis,
                                          element=element)
        np.testing.assert_allclose(k2, k1, rtol=1e-9, atol=1e-9 * np.abs(k1).max())
        np.testing.assert_allclose(m2, m1, rtol=1e-9)
        np.testing.assert_allclose(d2, d1, rtol=1e-9, atol=1e-9 * np.abs(d1).max())


# ---- node stencil (the explicit solver's layout of K) -------------------------------------------
@pytest.mark.parametrize("analysis", ["plane_strain", "axisymmetric"])
def test_node_stencil_equals_assembled_stiffness(analysis):
    # the default (condensed incompatible-mode) element: the stencil only needs symmetric 8x8 blocks
    """(K u)_i = sum_k blocks[k, :, :, i] @ u[neighbours[i, k]] for a batch of two designs."""
    pts, cells, _ = distorted_grid(5, 4, x0=0.2e-3, seed=3, amp=0.3)
    ke, _, _ = fem.element_matrices(pts, cells, *_mats(len(cells)), analysis=analysis)
    neighbours, blocks = fem.node_stencil(cells, np.stack([ke, 2.5 * ke]), len(pts))
    assert neighbours.shape == (len(pts), 9) and blocks.shape == (2, 9, 2, 2, len(pts))
    u = np.random.default_rng(0).normal(size=(len(pts), 2))
    ref = (fem.assemble_csr(cells, ke, len(pts)) @ u.ravel()).reshape(-1, 2)
    for scale, b in zip((1.0, 2.5), blocks):
        f = np.einsum("kabn,nkb->na", b, u[neighbours])
        np.testing.assert_allclose(f, scale * ref, rtol=0, atol=1e-12 * np.abs(ref).max())


# ---- bending: the incompatible-mode element does not lock -----------------------------------------
def _beam(nx, ny, length=10.0, height=1.0):
    xs, ys = np.linspace(0, length, nx + 1), np.linspace(-height / 2, height / 2, ny + 1)
    xx, yy = np.meshgrid(xs, ys)
    pts = np.stack([xx.ravel(), yy.ravel()], 1)
    idx = np.arange(len(pts)).reshape(ny + 1, nx + 1)
    cells = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    return pts, cells, idx


def _solve_static(pts, cells, ke, f, fixed):
    import scipy.sparse.linalg as spla

    k = fem.assemble_csr(cells, ke, len(pts)).tocsc()
    free = np.setdiff1d(np.arange(2 * len(pts)), fixed)
    u = np.zeros(2 * len(pts))
    u[free] = spla.spsolve(k[free][:, free], f[free])
    return u.reshape(-1, 2)


@pytest.mark.parametrize("ny", [1, 2])
def test_cantilever_tip_deflection_does_not_lock(ny):
    """Plane-strain cantilever (L/h = 10) under a tip shear, 10 elements long and 1 or 2 through the depth:
    q4i within 2 % of beam theory with shear, E' = E / (1 - nu^2); q4 locks (25-35 % too stiff)."""
    e, nu, p, length, h = 1e3, 0.25, 1.0, 10.0, 1.0
    pts, cells, idx = _beam(10, ny)
    ep, g = e / (1 - nu**2), e / (2 * (1 + nu))
    ref = p * length**3 / (3 * ep * h**3 / 12) + p * length / (5 / 6 * g * h)
    tip = idx[:, -1]
    f = np.zeros(2 * len(pts))
    f[2 * tip + 1] = p / len(tip)
    fixed = np.concatenate([2 * idx[:, 0], 2 * idx[:, 0] + 1])
    got = {}
    for element in fem.Q4_ELEMENTS:
        ke, _, _ = fem.element_matrices(pts, cells, *_mats(len(cells), e, nu), analysis="plane_strain", element=element)
        got[element] = _solve_static(pts, cells, ke, f, fixed)[tip, 1].mean() / ref
    assert abs(got["q4i"] - 1) < 0.02, got
    assert got["q4"] < 0.75, got


def test_pure_bending_centroid_stress_reads_the_condensed_modes():
    """End moment on a 2-element-deep beam: the centroid stress s_xx = M y / I exactly for q4i (the condensed
    modes enter the stress operator), and not for D B_c alone (q4: ~40 % low)."""
    e, nu, length, h, m = 1e3, 0.3, 10.0, 1.0, 2.0
    pts, cells, idx = _beam(8, 2, length, h)
    end = idx[:, -1]
    y = pts[end, 1]
    f = np.zeros(2 * len(pts))
    # consistent nodal forces of the linear traction s_xx = M y / I over the end face (two segments)
    seg = h / 2
    tr = m * y / (h**3 / 12)
    f[2 * end] = np.array([tr[0] * seg / 3 + tr[1] * seg / 6, tr[1] * 2 * seg / 3 + (tr[0] + tr[2]) * seg / 6,
                           tr[2] * seg / 3 + tr[1] * seg / 6])
    fixed = np.concatenate([2 * idx[:, 0], [2 * idx[1, 0] + 1]])  # x fixed on the root face, one y
    for element, tol in (("q4i", 1e-8), ("q4", None)):
        ke, _, db = fem.element_matrices(pts, cells, *_mats(len(cells), e, nu), analysis="plane_strain",
                                         element=element)
        u = _solve_static(pts, cells, ke, f, fixed)
        sig = np.einsum("ekj,ej->ek", db, u[cells].reshape(len(cells), 8))
        yc = pts[cells, 1].mean(1)
        want = m * yc / (h**3 / 12)
        err = np.abs(sig[:, 0] - want).max() / np.abs(want).max()
        if tol is None:
            assert err > 0.2, err
        else:
            assert err < tol, err
        np.testing.assert_allclose(sig[:, 2], 0.0, atol=1e-8 * np.abs(want).max())


def test_axisymmetric_clamped_plate_does_not_lock():
    """A clamped circular plate (radius a, thickness t = a / 20) under uniform pressure, 20 x 2 elements:
    centre deflection against Kirchhoff's p a^4 / (64 D) plus the shear term p a^2 / (4 k G t) (k = 5/6,
    Mindlin): q4i within 2 %, q4 far stiffer."""
    e, nu, a, t, p = 1e9, 0.3, 1.0, 0.05, 1e3
    xs, ys = np.linspace(0, a, 21), np.linspace(0, t, 3)
    xx, yy = np.meshgrid(xs, ys)
    pts = np.stack([xx.ravel(), yy.ravel()], 1)
    idx = np.arange(len(pts)).reshape(3, 21)
    cells = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    top = idx[-1]
    r = pts[top, 0]
    mid = 0.5 * (r[1:] + r[:-1])
    ring = np.pi * (np.concatenate([mid, [a]]) ** 2 - np.concatenate([[0.0], mid]) ** 2)  # tributary areas
    f = np.zeros(2 * len(pts))
    f[2 * top + 1] = -p * ring
    fixed = np.concatenate([2 * idx[:, -1], 2 * idx[:, -1] + 1, 2 * idx[:, 0]])  # clamped rim, symmetry axis
    dplate = e * t**3 / (12 * (1 - nu**2))
    ref = p * a**4 / (64 * dplate) + p * a**2 / (4 * (5 / 6) * e / (2 * (1 + nu)) * t)
    got = {}
    for element in fem.Q4_ELEMENTS:
        ke, _, _ = fem.element_matrices(pts, cells, *_mats(len(cells), e, nu), analysis="axisymmetric", element=element)
        got[element] = -_solve_static(pts, cells, ke, f, fixed)[idx[1, 0], 1] / ref
    assert abs(got["q4i"] - 1) < 0.02, got
    assert got["q4"] < 0.8, got


@pytest.mark.parametrize("analysis", ["axisymmetric", "plane_strain"])
@pytest.mark.parametrize("element", fem.Q4_ELEMENTS)
def test_jax_arrays_give_the_host_matrices(analysis, element):
    """One element definition: jax inputs (float64) give the NumPy path's stiffness, masses and stress
    operator, and the matrices are differentiable in the node coordinates (finite jacobian)."""
    import jax
    import jax.numpy as jnp

    pts, cells, _ = distorted_grid(4, 3, x0=0.0, seed=3, amp=0.3)
    mats = _mats(len(cells))
    host = fem.element_matrices(pts, cells, *mats, analysis=analysis, element=element)
    with jax.enable_x64(True):
        dev = fem.element_matrices(jnp.asarray(pts), cells, *map(jnp.asarray, mats), analysis=analysis,
                                   element=element)
        jac = jax.jacfwd(lambda p: fem.element_matrices(p, cells, *mats, analysis=analysis, element=element)[0])(
            jnp.asarray(pts))
    for a, b in zip(host, dev):
        np.testing.assert_allclose(np.asarray(b), a, rtol=0, atol=1e-13 * np.abs(a).max())
    assert np.isfinite(np.asarray(jac)).all()
