"""Bilinear quad (Q4) finite elements, small-strain linear elasticity, host-side NumPy (float64).

Analyses: ``plane_strain`` (per metre of depth) and ``axisymmetric`` (x = r, full 2*pi ring:
stiffness, mass and nodal forces are for the whole ring, so a nodal force is a total force [N]).
Strain vector: (eps_xx, eps_yy, gamma_xy, eps_zz) where eps_zz is the hoop strain u_r / r
(axisymmetric) or 0 (plane strain). Written by hand because the explicit solver needs the
per-element matrices as dense arrays for JAX; scikit-fem is used in the tests as the check.
"""
from __future__ import annotations

import numpy as np

_G = 1.0 / np.sqrt(3.0)
GAUSS_2x2 = np.array([[-_G, -_G], [_G, -_G], [_G, _G], [-_G, _G]])
_XI = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)


def shape_functions(xi: float, eta: float) -> tuple[np.ndarray, np.ndarray]:
    """Q4 shape functions N (4,) and their natural derivatives dN (2,4) at (xi, eta)."""
    n = 0.25 * (1 + _XI[:, 0] * xi) * (1 + _XI[:, 1] * eta)
    dn = 0.25 * np.stack([_XI[:, 0] * (1 + _XI[:, 1] * eta), _XI[:, 1] * (1 + _XI[:, 0] * xi)])
    return n, dn


def elasticity_matrix(youngs: np.ndarray, poisson: np.ndarray) -> np.ndarray:
    """(E,4,4) isotropic D for (xx, yy, xy, zz); valid for both plane strain and axisymmetry."""
    youngs = np.asarray(youngs, float)[:, None, None]
    nu = np.asarray(poisson, float)[:, None, None]
    lam = youngs * nu / ((1 + nu) * (1 - 2 * nu))
    mu = youngs / (2 * (1 + nu))
    base = np.array([[1, 1, 0, 1], [1, 1, 0, 1], [0, 0, 0, 0], [1, 1, 0, 1]], float)
    diag = np.diag([2.0, 2.0, 1.0, 2.0])
    return lam * base + mu * diag


def b_matrices(xy: np.ndarray, xi: float, eta: float, axisymmetric: bool):
    """B (E,4,8), integration weight (E,) without the Gauss weight, N (4,) at (xi, eta).

    Public: the solver's element operators and the objective's element integration
    (:func:`pcmgn_jax.metrics.objective_weights`) share this one definition of det J and 2 pi r.
    """
    n, dn = shape_functions(xi, eta)
    jac = np.einsum("ak,ekb->eab", dn, xy)  # (E,2,2): d(x,y)/d(xi,eta)
    det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
    if np.any(det <= 0):
        bad = int(np.argmin(det))
        raise ValueError(f"fem: element {bad} has a non-positive Jacobian ({det[bad]:.3e}); "
                         "check node ordering (counter-clockwise) and distortion")
    inv = np.linalg.inv(jac)
    dxy = np.einsum("eab,bk->eak", inv, dn)  # (E,2,4) physical derivatives
    ne = xy.shape[0]
    b = np.zeros((ne, 4, 8))
    b[:, 0, 0::2] = dxy[:, 0]
    b[:, 1, 1::2] = dxy[:, 1]
    b[:, 2, 0::2] = dxy[:, 1]
    b[:, 2, 1::2] = dxy[:, 0]
    r = xy[:, :, 0] @ n  # (E,) radius at the point
    if axisymmetric:
        b[:, 3, 0::2] = n[None, :] / np.maximum(r, 1e-300)[:, None]
        weight = det * 2.0 * np.pi * r
    else:
        weight = det
    return b, weight, n


def element_matrices(points: np.ndarray, cells: np.ndarray, youngs: np.ndarray,
                     poisson: np.ndarray, density: np.ndarray, *, analysis: str):
    """Per-element stiffness (E,8,8) [N/m], row-sum lumped nodal masses (E,4) [kg], and the
    centroid stress operator D B_c (E,4,8) [Pa/m] giving (s_xx, s_yy, s_xy, s_zz).

    dof order inside an element: (u_x0, u_y0, u_x1, u_y1, ...).
    """
    if analysis not in ("axisymmetric", "plane_strain"):
        raise ValueError(f"fem: unknown analysis {analysis!r}")
    axi = analysis == "axisymmetric"
    xy = points[cells]  # (E,4,2)
    # plane strain: row 3 of B is zero (eps_zz = 0) and row 3 of D then gives
    # sigma_zz = lambda (eps_xx + eps_yy), which enters the von Mises stress.
    d = elasticity_matrix(youngs, poisson)
    ke = np.zeros((len(cells), 8, 8))
    mass = np.zeros((len(cells), 4))
    for xi, eta in GAUSS_2x2:
        b, w, n = b_matrices(xy, xi, eta, axi)
        if not axi:
            b[:, 3, :] = 0.0
        ke += np.einsum("eki,ekl,elj->eij", b, d, b) * w[:, None, None]
        mass += np.asarray(density)[:, None] * n[None, :] * w[:, None]
    bc, _, _ = b_matrices(xy, 0.0, 0.0, axi)
    if not axi:
        bc[:, 3, :] = 0.0
    db = np.einsum("ekl,elj->ekj", d, bc)
    return ke, mass, db


def von_mises(stress: np.ndarray) -> np.ndarray:
    """von Mises stress [Pa] from (..., 4) = (s_xx, s_yy, s_xy, s_zz); works for numpy and jnp."""
    sxx, syy, sxy, szz = stress[..., 0], stress[..., 1], stress[..., 2], stress[..., 3]
    j2 = ((sxx - syy) ** 2 + (syy - szz) ** 2 + (szz - sxx) ** 2) / 6.0 + sxy**2
    return (3.0 * j2) ** 0.5


def node_stencil(cells: np.ndarray, ke: np.ndarray, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """The global stiffness as 2x2 node blocks over each node's neighbours (ELL layout), host
    NumPy: ``(K u)_i = sum_k blocks[..., k, :, :, i] @ u[neighbours[i, k]]``.

    ke (..., E, 8, 8) [N/m] with any leading batch axes. Returns neighbours (N, W) int64 (the
    nodes sharing an element with node i, sorted, i itself included; short rows padded with i
    and a zero block) and blocks (..., W, 2, 2, N) [N/m]. W is the largest neighbour count,
    9 on a conforming quad mesh. The same sums as :func:`assemble_csr`, arranged so that an
    explicit solver needs one gather per neighbour slot and no scatter.
    """
    n_el = cells.shape[0]
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
    batch = ke.shape[:-3]
    kb = ke.reshape(-1, n_el, 4, 2, 4, 2).transpose(1, 2, 4, 3, 5, 0).reshape(n_el * 16, 2, 2, -1)
    flat = np.zeros((n_nodes * width, 2, 2, kb.shape[-1]))
    np.add.at(flat, urow[pair] * width + slot[pair], kb)
    blocks = flat.reshape(n_nodes, width, 2, 2, -1).transpose(4, 1, 2, 3, 0)
    return neighbours, blocks.reshape(*batch, width, 2, 2, n_nodes)


def assemble_csr(cells: np.ndarray, ke: np.ndarray, n_nodes: int):
    """Global sparse stiffness (2N,2N) scipy CSR from element matrices (host, float64)."""
    import scipy.sparse as sp

    dofs = np.stack([2 * cells, 2 * cells + 1], axis=-1).reshape(len(cells), 8)
    rows = np.repeat(dofs, 8, axis=1).ravel()
    cols = np.tile(dofs, (1, 8)).ravel()
    return sp.csr_matrix((ke.ravel(), (rows, cols)), shape=(2 * n_nodes, 2 * n_nodes))
