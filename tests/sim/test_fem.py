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
    skfem = pytest.importorskip("skfem")
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    pts, cells, _ = distorted_grid(5, 4, seed=seed, amp=0.3)
    youngs, nu = 77e9, 0.21
    ke, _, _ = fem.element_matrices(pts, cells, *_mats(len(cells), youngs, nu), analysis="plane_strain")
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
    ke, _, _ = fem.element_matrices(pts, cells, *_mats(len(cells), youngs, nu), analysis="axisymmetric")
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
def _strain_and_forces(pts, cells, u, analysis, youngs=77e9, nu=0.21):
    ke, _, db = fem.element_matrices(pts, cells, *_mats(len(cells), youngs, nu), analysis=analysis)
    k = fem.assemble_csr(cells, ke, len(pts))
    f = (k @ u.ravel()).reshape(-1, 2)
    sig = np.einsum("ekj,ej->ek", db, u[cells].reshape(len(cells), 8))
    d = fem.elasticity_matrix(np.array([youngs]), np.array([nu]))[0]
    return f, sig, d, ke


@pytest.mark.parametrize("seed", [0, 5])
def test_patch_plane_strain(seed):
    pts, cells, boundary = distorted_grid(5, 4, seed=seed, amp=0.3)
    a = np.array([[2.0e-3, -0.7e-3], [1.1e-3, -1.5e-3]])
    b = np.array([3e-6, -2e-6])
    u = pts @ a.T + b
    f, sig, d, ke = _strain_and_forces(pts, cells, u, "plane_strain")
    scale = np.abs(ke).max() * np.abs(u).max()
    assert np.abs(f[~boundary]).max() < 1e-12 * scale
    assert np.abs(f[boundary]).max() > 1e-3 * scale  # the traction is really there
    eps = np.array([a[0, 0], a[1, 1], a[0, 1] + a[1, 0], 0.0])
    np.testing.assert_allclose(sig, np.broadcast_to(d @ eps, sig.shape), rtol=1e-12, atol=1e-12 * np.abs(d @ eps).max())
    # boundary forces are the tractions of the uniform stress: they sum to zero
    np.testing.assert_allclose(f.sum(0), 0.0, atol=1e-12 * scale)


@pytest.mark.parametrize("x0", [0.0, 1e-3])  # touching the axis, and off the axis
def test_patch_axisymmetric(x0):
    """u_r = a r, u_z = b z + c: uniform strain (a, b, 0, a) incl. the hoop strain; it is in
    equilibrium without body force, so interior nodal forces vanish."""
    pts, cells, boundary = distorted_grid(5, 4, x0=x0, seed=2, amp=0.3)
    aa, bb, cc = 1.7e-3, -0.9e-3, 4e-6
    u = np.stack([aa * pts[:, 0], bb * pts[:, 1] + cc], 1)
    f, sig, d, ke = _strain_and_forces(pts, cells, u, "axisymmetric")
    scale = np.abs(ke).max() * np.abs(u).max()
    assert np.abs(f[~boundary]).max() < 1e-12 * scale
    eps = np.array([aa, bb, 0.0, aa])
    np.testing.assert_allclose(sig, np.broadcast_to(d @ eps, sig.shape), rtol=1e-12,
                               atol=1e-12 * np.abs(d @ eps).max())
    # axial resultant: the bottom and top faces carry s_zz * pi (r1^2 - r0^2) each, opposite
    top = np.isclose(pts[:, 1], pts[:, 1].max())
    r0, r1 = x0, x0 + 2e-3
    assert f[top, 1].sum() == pytest.approx((d @ eps)[1] * np.pi * (r1**2 - r0**2), rel=1e-10)


@pytest.mark.parametrize("analysis", ["plane_strain", "axisymmetric"])
def test_rigid_vertical_translation_is_force_free(analysis):
    pts, cells, _ = distorted_grid(4, 4, seed=7, amp=0.3)
    u = np.zeros_like(pts)
    u[:, 1] = 1e-5
    f, sig, _, ke = _strain_and_forces(pts, cells, u, analysis)
    assert np.abs(f).max() < 1e-12 * np.abs(ke).max() * 1e-5
    assert np.abs(sig).max() < 1e-12 * 77e9 * 1e-5 / 1e-3
    if analysis == "plane_strain":  # in-plane rigid rotation too (not rigid in axisymmetry)
        th = 1e-4
        u = th * np.stack([-pts[:, 1], pts[:, 0]], 1)
        f, sig, _, _ = _strain_and_forces(pts, cells, u, analysis)
        assert np.abs(f).max() < 1e-12 * np.abs(ke).max() * np.abs(u).max()
    else:  # a radial translation stretches the hoops
        u = np.zeros_like(pts)
        u[:, 0] = 1e-5
        f, _, _, _ = _strain_and_forces(pts, cells, u, analysis)
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


def test_element_stiffness_invariant_under_rigid_motion_of_mesh():
    """Translating the mesh (plane strain) or shifting it along the axis (axisymmetric) does
    not change the element matrices."""
    pts, cells, _ = distorted_grid(3, 2, x0=0.2e-3, seed=9)
    for analysis, shift in (("plane_strain", [5e-3, -2e-3]), ("axisymmetric", [0.0, 7e-3])):
        k1, m1, d1 = fem.element_matrices(pts, cells, *_mats(len(cells)), analysis=analysis)
        k2, m2, d2 = fem.element_matrices(pts + np.array(shift), cells, *_mats(len(cells)), analysis=analysis)
        np.testing.assert_allclose(k2, k1, rtol=1e-9, atol=1e-9 * np.abs(k1).max())
        np.testing.assert_allclose(m2, m1, rtol=1e-9)
        np.testing.assert_allclose(d2, d1, rtol=1e-9, atol=1e-9 * np.abs(d1).max())


# ---- node stencil (the explicit solver's layout of K) -------------------------------------------
@pytest.mark.parametrize("analysis", ["plane_strain", "axisymmetric"])
def test_node_stencil_equals_assembled_stiffness(analysis):
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
