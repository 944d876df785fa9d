"""Bilinear quad (Q4) finite elements, small-strain linear elasticity, host-side NumPy (float64).

Analyses: ``plane_strain`` (per metre of depth) and ``axisymmetric`` (x = r, full 2*pi ring:
stiffness, mass and nodal forces are for the whole ring, so a nodal force is a total force [N]).
Strain vector: (eps_xx, eps_yy, gamma_xy, eps_zz) where eps_zz is the hoop strain u_r / r
(axisymmetric) or 0 (plane strain). Written by hand because the explicit solver needs the
per-element matrices as dense arrays for JAX; scikit-fem is used in the tests as the check.

Elements (:data:`Q4_ELEMENTS`, the default first):

- ``q4i``: the Q4 with incompatible modes, statically condensed (Wilson, Taylor, Doherty & Ghaboussi 1973,
  "Incompatible displacement models"; Taylor, Beresford & Wilson 1976, "A non-conforming element for stress
  analysis", IJNME 10: the "QM6" form, derivatives of the modes taken with the centre Jacobian). Two bubble
  modes per displacement component, (1 - xi^2) and (1 - eta^2), add the bending the bilinear field lacks, so
  the element does not lock in bending (the full-integration Q4 does: a thin layer bent through one or two
  elements is ~10 % too stiff on the ``cpu`` mesh). The modes' strain operator G is made orthogonal to
  constant stress over the element volume, G~ = G - (int G dV) / V, Simo & Rifai 1990 (IJNME 29, eq. 3.8 /
  the patch-test condition of §4.2): in plane strain the QM6 form already satisfies it (the subtraction
  removes round-off only); in axisymmetry the weight 2 pi r and the hoop row M / r break it, and the
  subtraction restores the patch test there. With the internal dofs a condensed once per element,
  K = K_uu - K_ua K_aa^-1 K_au is a constant 8x8 stiffness (the explicit loop applies it unchanged), the
  modes carry no mass (lumped mass from the bilinear shape functions, as for ``q4``), and the centroid
  stress reads the condensed modes: sigma_c = D (B_c - G~_c K_aa^-1 K_au) u (the ``db`` operator).
  CalculiX's ``C3D8I`` is the 3D element of this family.
- ``q4``: the fully integrated bilinear quad (2x2 Gauss), kept for comparison: it locks in bending.
"""
from __future__ import annotations

import numpy as np

_G = 1.0 / np.sqrt(3.0)
GAUSS_2x2 = np.array([[-_G, -_G], [_G, -_G], [_G, _G], [-_G, _G]])
_XI = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)

#: element formulations, the default first (module docstring)
Q4_ELEMENTS = ("q4i", "q4")
DEFAULT_ELEMENT = Q4_ELEMENTS[0]


def array_module(*arrays):
    """The array module of the inputs: ``jax.numpy`` when any is a jax array (or tracer), else NumPy.
    One definition of the element serves both: the host path (NumPy, float64) and the differentiable
    solver (:mod:`pcmgn_jax.sim.differentiable`, jax arrays of the node coordinates and materials)."""
    if all(isinstance(a, (np.ndarray, np.generic, float, int, list, tuple)) for a in arrays):
        return np
    import jax.numpy as jnp
    return jnp


def shape_functions(xi: float, eta: float) -> tuple[np.ndarray, np.ndarray]:
    """Q4 shape functions N (4,) and their natural derivatives dN (2,4) at (xi, eta)."""
    n = 0.25 * (1 + _XI[:, 0] * xi) * (1 + _XI[:, 1] * eta)
    dn = 0.25 * np.stack([_XI[:, 0] * (1 + _XI[:, 1] * eta), _XI[:, 1] * (1 + _XI[:, 0] * xi)])
    return n, dn


def elasticity_matrix(youngs, poisson):
    """(E,4,4) isotropic D [Pa] for (xx, yy, xy, zz) from youngs (E,) [Pa] and poisson (E,); valid for both
    plane strain and axisymmetry. NumPy or jax arrays (:func:`array_module`)."""
    xp = array_module(youngs, poisson)
    youngs = xp.asarray(youngs, float)[:, None, None]
    nu = xp.asarray(poisson, float)[:, None, None]
    lam = youngs * nu / ((1 + nu) * (1 - 2 * nu))
    mu = youngs / (2 * (1 + nu))
    base = np.array([[1, 1, 0, 1], [1, 1, 0, 1], [0, 0, 0, 0], [1, 1, 0, 1]], float)
    diag = np.diag([2.0, 2.0, 1.0, 2.0])
    return lam * base + mu * diag


def _det2(jac):
    return jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]


def _inv2(jac, det):
    """Inverse of (E,2,2) matrices with their determinants (E,): the adjugate over det."""
    xp = array_module(jac)
    adj = xp.stack([xp.stack([jac[:, 1, 1], -jac[:, 0, 1]], -1), xp.stack([-jac[:, 1, 0], jac[:, 0, 0]], -1)], 1)
    return adj / det[:, None, None]


def _strain_rows(dx, dy, hoop, n_cols: int):
    """(E,4,2 n_cols) strain operator of a 2-component field with ``n_cols`` functions per component, the
    x component's functions first or interleaved: rows (xx, yy, xy, zz) from the physical derivatives dx,
    dy (E,n_cols) and the hoop row's functions over r (E,n_cols) (zeros in plane strain)."""
    xp = array_module(dx, dy, hoop)
    zero = xp.zeros_like(dx)
    rows = [(dx, zero), (zero, dy), (dy, dx), (hoop, zero)]
    return xp.stack([xp.stack([a, b], -1).reshape(dx.shape[0], 2 * n_cols) for a, b in rows], 1)


def b_matrices(xy, xi: float, eta: float, axisymmetric: bool):
    """B (E,4,8), integration weight (E,) without the Gauss weight, N (4,) at (xi, eta); xy (E,4,2) [m].

    Public: the solver's element operators and the objective's element integration
    (:func:`pcmgn_jax.metrics.objective_weights`) share this one definition of det J and 2 pi r.
    NumPy or jax arrays (:func:`array_module`); the radius is floored at 1e-300 m (finite on the axis).
    """
    xp = array_module(xy)
    n, dn = shape_functions(xi, eta)
    jac = xp.einsum("ak,ekb->eab", dn, xy)  # (E,2,2): d(x,y)/d(xi,eta)
    det = _det2(jac)
    if xp is np and np.any(det <= 0):
        bad = int(np.argmin(det))
        raise ValueError(f"fem: element {bad} has a non-positive Jacobian ({det[bad]:.3e}); "
                         "check node ordering (counter-clockwise) and distortion")
    dxy = xp.einsum("eab,bk->eak", _inv2(jac, det), dn)  # (E,2,4) physical derivatives
    r = xy[:, :, 0] @ n  # (E,) radius at the point
    if axisymmetric:
        hoop = n[None, :] / xp.maximum(r, 1e-300)[:, None]
        weight = det * 2.0 * np.pi * r
    else:
        hoop = xp.zeros_like(dxy[:, 0])
        weight = det
    # dof order (u_x0, u_y0, u_x1, ...): the x and y functions interleave
    return _strain_rows(dxy[:, 0], dxy[:, 1], hoop, 4), weight, n


def _incompatible_g(xy, xi: float, eta: float, axisymmetric: bool):
    """The incompatible modes' strain operator G (E,4,4) at (xi, eta), before the patch-test correction.

    Modes (Wilson et al. 1973): u_x and u_y each get a1 (1 - xi^2) + a2 (1 - eta^2); internal dofs ordered
    (a1x, a2x, a1y, a2y). The in-plane derivatives use the Jacobian at the element centre scaled by
    det J0 / det J (Taylor, Beresford & Wilson 1976, "QM6"); the hoop row is M / r (axisymmetric).
    """
    xp = array_module(xy)
    modes = np.array([1.0 - xi * xi, 1.0 - eta * eta])
    dnat = np.array([[-2.0 * xi, 0.0], [0.0, -2.0 * eta]])       # d(mode)/d(xi, eta): rows xi, eta
    _, dn0 = shape_functions(0.0, 0.0)
    n, dn = shape_functions(xi, eta)
    jac0 = xp.einsum("ak,ekb->eab", dn0, xy)
    det0, det = _det2(jac0), _det2(xp.einsum("ak,ekb->eab", dn, xy))
    dxy = xp.einsum("eab,bk->eak", _inv2(jac0, det0), dnat) * (det0 / det)[:, None, None]  # (E,2,2)
    if axisymmetric:
        hoop = modes[None, :] / xp.maximum(xy[:, :, 0] @ n, 1e-300)[:, None]
    else:
        hoop = xp.zeros_like(dxy[:, 0])
    # internal dofs (a1x, a2x, a1y, a2y): the x modes first, then the y modes
    g = _strain_rows(dxy[:, 0], dxy[:, 1], hoop, 2)
    return g[..., np.array([0, 2, 1, 3])]


def element_matrices(points, cells, youngs, poisson, density, *, analysis: str,
                     element: str = DEFAULT_ELEMENT):
    """Per-element stiffness (E,8,8) [N/m], row-sum lumped nodal masses (E,4) [kg], and the
    centroid stress operator D B_c (E,4,8) [Pa/m] giving (s_xx, s_yy, s_xy, s_zz).

    points (N,2) [m], cells (E,4), youngs / poisson / density (E,) [Pa, -, kg/m^3]. ``element``: one of
    :data:`Q4_ELEMENTS` (module docstring); for ``q4i`` the stiffness and the stress operator are those of the
    condensed element. dof order inside an element: (u_x0, u_y0, u_x1, u_y1, ...). NumPy in -> NumPy out
    (the host path, float64); jax arrays of the points or materials in -> jax out, differentiable (the
    same formulas: :func:`array_module`).
    """
    if analysis not in ("axisymmetric", "plane_strain"):
        raise ValueError(f"fem: unknown analysis {analysis!r}")
    if element not in Q4_ELEMENTS:
        raise ValueError(f"fem: unknown element {element!r}; one of {Q4_ELEMENTS}")
    xp = array_module(points, youngs, poisson, density)
    axi = analysis == "axisymmetric"
    xy = xp.asarray(points)[cells]  # (E,4,2)
    # plane strain: row 3 of B is zero (eps_zz = 0) and row 3 of D then gives
    # sigma_zz = lambda (eps_xx + eps_yy), which enters the von Mises stress.
    d = elasticity_matrix(youngs, poisson)
    bs, gs, ws = [], [], []
    mass = 0.0
    for xi, eta in GAUSS_2x2:
        b, w, n = b_matrices(xy, xi, eta, axi)
        bs.append(b)
        ws.append(w)
        gs.append(_incompatible_g(xy, xi, eta, axi) if element == "q4i" else None)
        mass = mass + xp.asarray(density)[:, None] * n[None, :] * w[:, None]
    ke = sum(xp.einsum("eki,ekl,elj->eij", b, d, b) * w[:, None, None] for b, w in zip(bs, ws))
    bc, _, _ = b_matrices(xy, 0.0, 0.0, axi)
    if element == "q4":
        return ke, mass, xp.einsum("ekl,elj->ekj", d, bc)
    # orthogonality to constant stress (Simo & Rifai 1990): subtract the volume mean of G
    vol = sum(ws)
    g_mean = sum(g * w[:, None, None] for g, w in zip(gs, ws)) / vol[:, None, None]
    gs = [g - g_mean for g in gs]
    k_aa = sum(xp.einsum("eki,ekl,elj->eij", g, d, g) * w[:, None, None] for g, w in zip(gs, ws))
    k_au = sum(xp.einsum("eki,ekl,elj->eij", g, d, b) * w[:, None, None] for g, w, b in zip(gs, ws, bs))
    cond = xp.linalg.solve(k_aa, k_au)                      # (E,4,8): a = -cond @ u
    ke = ke - xp.einsum("eai,eaj->eij", k_au, cond)
    ke = 0.5 * (ke + xp.swapaxes(ke, 1, 2))                 # symmetric to round-off
    gc = _incompatible_g(xy, 0.0, 0.0, axi) - g_mean
    return ke, mass, xp.einsum("ekl,elj->ekj", d, bc - xp.einsum("eka,eaj->ekj", gc, cond))


def von_mises(stress):
    """von Mises stress [Pa] from (..., 4) = (s_xx, s_yy, s_xy, s_zz); works for numpy and jnp. The root is
    guarded (0 where J2 = 0, with a zero gradient there, not NaN: the unloaded first frame)."""
    xp = array_module(stress)
    sxx, syy, sxy, szz = stress[..., 0], stress[..., 1], stress[..., 2], stress[..., 3]
    j2 = ((sxx - syy) ** 2 + (syy - szz) ** 2 + (szz - sxx) ** 2) / 6.0 + sxy**2
    pos = j2 > 0
    return xp.where(pos, (3.0 * xp.where(pos, j2, 1.0)) ** 0.5, 0.0)


def stencil_index(cells: np.ndarray, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Host side: where each element's 2x2 node blocks go in :func:`node_stencil`'s layout.

    Returns neighbours (N, W) int64 (as :func:`node_stencil`) and dest (E*16,) int64: the flat slot
    ``node * W + k`` of block (a, b) of element e, in the order ``e * 16 + a * 4 + b``."""
    rows = np.repeat(cells, 4, axis=1).ravel()          # (E*16,) node a of pair (a, b)
    cols = np.tile(cells, (1, 4)).ravel()               # node b
    key = rows.astype(np.int64) * n_nodes + cols
    uniq, pair = np.unique(key, return_inverse=True)
    urow, ucol = uniq // n_nodes, uniq % n_nodes
    first = np.searchsorted(urow, np.arange(n_nodes))
    slot = np.arange(len(uniq)) - first[urow]
    width = int(slot.max()) + 1
    neighbours = np.repeat(np.arange(n_nodes)[:, None], width, axis=1)
    neighbours[urow, slot] = ucol
    return neighbours, (urow[pair] * width + slot[pair]).astype(np.int64)


def node_stencil(cells: np.ndarray, ke, n_nodes: int, index=None):
    """The global stiffness as 2x2 node blocks over each node's neighbours (ELL layout):
    ``(K u)_i = sum_k blocks[..., k, :, :, i] @ u[neighbours[i, k]]``.

    ke (..., E, 8, 8) [N/m] with any leading batch axes, NumPy (host) or jax (differentiable: a scatter-add).
    Returns neighbours (N, W) int64 (the nodes sharing an element with node i, sorted, i itself included;
    short rows padded with i and a zero block) and blocks (..., W, 2, 2, N) [N/m]. W is the largest
    neighbour count, 9 on a conforming quad mesh. The same sums as :func:`assemble_csr`, arranged so that
    an explicit solver needs one gather per neighbour slot and no scatter. ``index``: a precomputed
    :func:`stencil_index` of these cells.
    """
    xp = array_module(ke)
    neighbours, dest = stencil_index(cells, n_nodes) if index is None else index
    width, n_el = neighbours.shape[1], cells.shape[0]
    batch = ke.shape[:-3]
    kb = ke.reshape(-1, n_el, 4, 2, 4, 2).transpose(1, 2, 4, 3, 5, 0).reshape(n_el * 16, 2, 2, -1)
    if xp is np:
        flat = np.zeros((n_nodes * width, 2, 2, kb.shape[-1]))
        np.add.at(flat, dest, kb)
    else:
        flat = xp.zeros((n_nodes * width, 2, 2, kb.shape[-1]), kb.dtype).at[dest].add(kb)
    blocks = flat.reshape(n_nodes, width, 2, 2, -1).transpose(4, 1, 2, 3, 0)
    return neighbours, blocks.reshape(*batch, width, 2, 2, n_nodes)


def assemble_csr(cells: np.ndarray, ke: np.ndarray, n_nodes: int):
    """Global sparse stiffness (2N,2N) scipy CSR from element matrices (host, float64)."""
    import scipy.sparse as sp

    dofs = np.stack([2 * cells, 2 * cells + 1], axis=-1).reshape(len(cells), 8)
    rows = np.repeat(dofs, 8, axis=1).ravel()
    cols = np.tile(dofs, (1, 8)).ravel()
    return sp.csr_matrix((ke.ravel(), (rows, cols)), shape=(2 * n_nodes, 2 * n_nodes))
