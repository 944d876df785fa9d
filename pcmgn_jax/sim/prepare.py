"""Host-side preparation of a solver batch: meshes, element operators, lumped masses, contact
penalties and the stable time step (NumPy / SciPy, float64, once per batch).

The stable step includes the contact springs: dt = safety * 2 / sqrt(w_mesh^2 + w_c^2), w_mesh^2 the
largest eigenvalue of M^-1/2 K M^-1/2 (scipy Lanczos), w_c^2 a Gershgorin bound of M^-1 K_contact
(see :mod:`pcmgn_jax.sim.solver` for why the bound, not the coupled eigenvalue, sets the step).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla

from pcmgn_jax.scene import Scene
from pcmgn_jax.sim import fem
from pcmgn_jax.sim.mesh import Mesh, MeshSpec, build_mesh, mesh_spec


@dataclass(frozen=True)
class SolverSettings:
    """safety: fraction of the stable time step; penalty_factor: k_p = factor * E'/h [N/m^3]
    with E' the plane-strain modulus of the softer contact body and h the master element size;
    energy_tol: allowed |E(t) - E(0)| / KE(0); element: the Q4 formulation, one of
    :data:`pcmgn_jax.sim.fem.Q4_ELEMENTS` (``q4i``, incompatible modes condensed, the default; ``q4``, full
    integration, which locks in bending: kept for comparison); dtype: 'float32' or 'float64' (float64 needs
    ``jax.enable_x64``); designs_per_call: designs of a batch integrated together in one
    compiled call (0 = the device's default, :func:`pcmgn_jax.sim.solver.designs_per_call`:
    64 on an accelerator, one at a time on CPU, where the vectorised batch of 8 runs at 0.7-0.8x
    the per-design throughput of single runs: benchmarks/README §3); the last call of a batch
    that needs several is padded to this size, so every call shares one compilation
    (:func:`pcmgn_jax.sim.solver.call_size`)."""

    safety: float = 0.9
    penalty_factor: float = 1.0
    energy_tol: float = 0.01
    element: str = fem.DEFAULT_ELEMENT
    dtype: str = "float32"
    designs_per_call: int = 0


#: the settings every entry point defaults to (frozen, so one shared instance)
DEFAULT_SETTINGS = SolverSettings()


@dataclass
class Prepared:
    """Host-side arrays for a batch of B designs sharing one topology (leading axis B)."""

    mesh: Mesh                # mesh of the first design (topology shared)
    points: np.ndarray        # (B,N,2) reference coordinates [m]
    ke: np.ndarray            # (B,E,8,8) element stiffness [N/m]
    db: np.ndarray            # (B,E,4,8) centroid stress operator [Pa/m]
    mass: np.ndarray          # (B,N) lumped nodal mass [kg]
    k_slave: np.ndarray       # (B,S) penalty stiffness per slave node [N/m]
    slaves: np.ndarray        # (S,) ball surface node ids
    masters: np.ndarray       # (M,) top-surface node ids, sorted by x
    node_slots: np.ndarray    # (N,4) indices into the flattened (E*4 + 1) element-node slots
    avg_weight: np.ndarray    # (N,4) nodal-averaging weights of those slots (own part only)
    free: np.ndarray          # (N,2) 1.0 where the dof is free
    omega2_mesh: np.ndarray   # (B,) largest eigenvalue of M^-1 K [1/s^2]
    omega2_contact: np.ndarray  # (B,) Gershgorin bound of M^-1 K_contact [1/s^2]
    omega2_coupled: np.ndarray  # (B,) largest eigenvalue of M^-1 (K + K_contact) [1/s^2] (reported)
    dt_stable: float          # [s] min over the batch, safety applied


def _node_slots(cells: np.ndarray, n_nodes: int, cell_part: np.ndarray, node_part: np.ndarray):
    """For each node, up to 4 (element, corner) slots; padding points at the zero slot E*4."""
    n_el = cells.shape[0]
    slots = np.full((n_nodes, 4), 4 * n_el, np.int64)
    weight = np.zeros((n_nodes, 4))
    fill = np.zeros(n_nodes, np.int64)
    for e in range(n_el):
        for k in range(4):
            node = cells[e, k]
            if fill[node] >= 4:
                raise ValueError(f"solver: node {node} belongs to more than 4 quads")
            slots[node, fill[node]] = 4 * e + k
            weight[node, fill[node]] = 1.0 if cell_part[e] == node_part[node] else 0.0
            fill[node] += 1
    weight /= np.maximum(weight.sum(axis=1, keepdims=True), 1.0)
    return slots, weight


def _largest_omega2(k, minv_sqrt, free_dofs) -> float:
    """Largest eigenvalue [1/s^2] of M^-1/2 K M^-1/2 on the free dofs (scipy Lanczos, float64)."""
    kff = k[free_dofs][:, free_dofs]
    op = spla.LinearOperator(kff.shape, matvec=lambda x: minv_sqrt * (kff @ (minv_sqrt * x)), dtype=float)
    # a fixed start vector: ARPACK's default is random per call, so the estimate's last digits would
    # depend on how many calls the process made before (sharded and unsharded datasets must agree)
    v0 = np.random.default_rng(0).standard_normal(kff.shape[0])
    return float(spla.eigsh(op, k=1, which="LA", return_eigenvectors=False, tol=1e-4, v0=v0)[0])


def _contact_stiffness(slaves, masters, seg, t, k_slave, n_nodes):
    """Penalty springs as a (2N,2N) CSR matrix [N/m]: sum_s k_s g_s g_s^T with g_s the gradient
    of slave s's vertical gap over master segment ``seg[s]`` at coordinate ``t[s]``."""
    import scipy.sparse as sp

    dofs = np.stack([2 * slaves + 1, 2 * masters[seg] + 1, 2 * masters[seg + 1] + 1], axis=1)  # (S,3)
    g = np.stack([np.ones_like(t), -(1.0 - t), -t], axis=1)
    vals = k_slave[:, None, None] * g[:, :, None] * g[:, None, :]
    rows = np.repeat(dofs, 3, axis=1).ravel()
    cols = np.tile(dofs, (1, 3)).ravel()
    return sp.csr_matrix((vals.ravel(), (rows, cols)), shape=(2 * n_nodes, 2 * n_nodes))


def _tributary(x, axisymmetric: bool):
    """Tributary area [m^2] (axisymmetric ring) or length [m] (plane strain) of sorted x [m] (S,);
    NumPy or jax (differentiable in x)."""
    xp = fem.array_module(x)
    mid = 0.5 * (x[1:] + x[:-1])
    left = xp.maximum(xp.concatenate([xp.maximum(x[:1] - (mid[:1] - x[:1]), 0.0), mid]), 0.0)
    right = xp.concatenate([mid, x[-1:] + (x[-1:] - mid[-1:])])
    if axisymmetric:
        return np.pi * (right**2 - left**2)
    return right - left


def soft_modulus(top_youngs, top_poisson, ball_youngs, ball_poisson):
    """E' [Pa] of the softer contact body: min of the plane-strain moduli E / (1 - nu^2) of the top layer
    and the ball (the penalty's scale, :func:`slave_penalty`); floats or jax scalars."""
    xp = fem.array_module(top_youngs, top_poisson, ball_youngs, ball_poisson)
    return xp.minimum(top_youngs / (1 - top_poisson**2), ball_youngs / (1 - ball_poisson**2))


def slave_penalty(x_slaves, x_masters, e_soft, *, factor: float, axisymmetric: bool):
    """Penalty stiffness per slave node k_s [N/m] = factor * E'/h [N/m^3] times the slave's tributary area
    [m^2] (length in plane strain), h [m] the first master segment; x of the slaves (S,) and masters (M,)
    sorted [m], E' [Pa] (:func:`soft_modulus`). NumPy or jax."""
    return factor * e_soft / (x_masters[1] - x_masters[0]) * _tributary(x_slaves, axisymmetric)


def _material_arrays(scene: Scene, cell_part: np.ndarray):
    ball = scene.ball
    props = np.array([[ball.youngs, ball.poisson, ball.density]] +
                     [[layer.youngs, layer.poisson, layer.density] for layer in scene.layers])
    return props[cell_part, 0], props[cell_part, 1], props[cell_part, 2]


def prepare(scenes: Sequence[Scene], preset: str | MeshSpec,
            settings: SolverSettings = DEFAULT_SETTINGS) -> Prepared:
    """Mesh, element matrices, masses, penalty and stable step for designs of one topology."""
    spec = mesh_spec(preset)
    meshes = [build_mesh(s, spec) for s in scenes]
    m0 = meshes[0]
    for i, m in enumerate(meshes[1:], 1):
        if m.cells.shape != m0.cells.shape or not np.array_equal(m.cells, m0.cells):
            raise ValueError(f"solver: design {i} has a different mesh topology than design 0")
    axi = scenes[0].analysis == "axisymmetric"
    n = m0.n_nodes
    slots, avg_w = _node_slots(m0.cells, n, m0.cell_part, m0.node_part)
    free = (~m0.fixed).astype(float)
    free_dofs = np.flatnonzero(free.ravel() > 0)
    slaves = m0.ball_surface
    masters = m0.panel_top[np.argsort(m0.points[m0.panel_top, 0])]
    out = {k: [] for k in ("points", "ke", "db", "mass", "k_slave", "w2m", "w2c", "w2t")}
    for scene, m in zip(scenes, meshes):
        youngs, poisson, density = _material_arrays(scene, m.cell_part)
        ke, me, db = fem.element_matrices(m.points, m.cells, youngs, poisson, density,
                                          analysis=scene.analysis, element=settings.element)
        mass = np.zeros(n)
        np.add.at(mass, m.cells, me)
        k_glob = fem.assemble_csr(m.cells, ke, n)
        minv = 1.0 / np.sqrt(np.repeat(mass, 2)[free_dofs])
        w2m = _largest_omega2(k_glob, minv, free_dofs)
        xm = m.points[masters, 0]
        # each design's own contact bodies set its penalty (a stack family varies the top layer's modulus)
        top, ball = scene.layers[0], scene.ball
        e_soft = soft_modulus(top.youngs, top.poisson, ball.youngs, ball.poisson)
        k_s = slave_penalty(m.points[slaves, 0], xm, e_soft, factor=settings.penalty_factor, axisymmetric=axi)
        # contact bound: each slave spring on its own node, and the springs a master can see
        ksum = np.zeros(len(masters))
        xs = m.points[slaves, 0]
        j = np.clip(np.searchsorted(xm, xs) - 1, 0, len(masters) - 2)
        t = np.clip((xs - xm[j]) / (xm[j + 1] - xm[j]), 0.0, 1.0)
        np.add.at(ksum, j, k_s * (1 - t))
        np.add.at(ksum, j + 1, k_s * t)
        # Gershgorin bound of M^-1 K_contact (rows of slaves and of masters); Weyl's inequality
        # then bounds the coupled system by w_mesh^2 + w_c^2, which sets the step.
        w2c = 2.0 * max(float(np.max(k_s / mass[slaves])), float(np.max(ksum / mass[masters])))
        # Reported, not used for the step: the largest eigenvalue of M^-1 (K + K_c) with every
        # spring engaged at the reference slave positions. It is only ~9 % above w_mesh^2 (the
        # Weyl bound is 60-70 % above), but a step from it (safety 0.9) let a batch run of the
        # 150/150 um design gain 1.4 % energy near separation (frame 85, cpu mesh): the sliding,
        # deformed contact is stiffer than this linearisation, and the Weyl bound's margin holds.
        w2t = _largest_omega2(k_glob + _contact_stiffness(slaves, masters, j, t, k_s, n), minv,
                              free_dofs)
        for key, val in (("points", m.points), ("ke", ke), ("db", db), ("mass", mass),
                         ("k_slave", k_s), ("w2m", w2m), ("w2c", w2c), ("w2t", w2t)):
            out[key].append(val)
    w2m, w2c, w2t = (np.asarray(out[k]) for k in ("w2m", "w2c", "w2t"))
    dt = settings.safety * 2.0 / float(np.sqrt(np.max(w2m + w2c)))
    return Prepared(mesh=m0, points=np.stack(out["points"]), ke=np.stack(out["ke"]),
                    db=np.stack(out["db"]), mass=np.stack(out["mass"]),
                    k_slave=np.stack(out["k_slave"]), slaves=slaves, masters=masters,
                    node_slots=slots, avg_weight=avg_w, free=free, omega2_mesh=w2m,
                    omega2_contact=w2c, omega2_coupled=w2t, dt_stable=dt)
