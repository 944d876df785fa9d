"""Linear static solves of a scene's panel on the solver's own mesh and element (host, SciPy, float64).

The check of the element against CalculiX's static decks (:func:`pcmgn_jax.data.exporters.calculix.static_inp_text`,
``experiments.calculix_locking``): the same model with the impact replaced by a uniform pressure on the top
layer's upper faces within a radius of the axis, the ball's nodes held, the panel's supports as in the
dynamic run (clamped plate bottom, symmetry axis). Also the nodal stress recovery both codes' static fields are
read with, so a CalculiX displacement field and the built-in one are turned into von Mises by one rule.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spla

from pcmgn_jax.scene import Scene
from pcmgn_jax.sim import fem
from pcmgn_jax.sim.mesh import Mesh, MeshSpec, build_mesh
from pcmgn_jax.sim.prepare import _material_arrays, _node_slots


def recovered_von_mises(u: np.ndarray, scene: Scene, mesh: Mesh, element: str = fem.DEFAULT_ELEMENT) -> np.ndarray:
    """Nodal von Mises [Pa] (T, N) of displacements u (T, N, 2) [m] on ``mesh``: the ``element``'s centroid
    stress (the condensed modes included for ``q4i``) averaged over each node's own part, the solver's rule
    (:func:`pcmgn_jax.sim.integrate._frame_stress`)."""
    from pcmgn_jax.sim.integrate import _frame_stress

    youngs, poisson, density = _material_arrays(scene, mesh.cell_part)
    _, _, db = fem.element_matrices(mesh.points, mesh.cells, youngs, poisson, density, analysis=scene.analysis,
                                    element=element)
    slots, weight = _node_slots(mesh.cells, mesh.n_nodes, mesh.cell_part, mesh.node_part)
    rigid_x = scene.analysis == "plane_strain"
    # float32, the solver's own precision for this step (the element-mean displacement removed first)
    return np.stack([np.asarray(_frame_stress(ut, db, mesh.cells, slots, weight, rigid_x))
                     for ut in np.asarray(u, np.float32)])


def pressure_loads(mesh: Mesh, pressure: float, radius: float, axisymmetric: bool) -> np.ndarray:
    """Consistent nodal forces (N, 2) [N] of a uniform ``pressure`` [Pa] (> 0 pushes down) on the top layer's upper
    edges that lie wholly within ``radius`` [m] of the axis (CalculiX's loaded faces): per edge r_a..r_b, the
    linear shape functions integrated against 2 pi r (axisymmetric: F_a = 2 pi p (r_b - r_a)(2 r_a + r_b) / 6)
    or 1 (plane strain, per metre of depth)."""
    top = np.asarray(mesh.panel_top)
    top = top[np.argsort(mesh.points[top, 0])]
    x = mesh.points[top, 0]
    f = np.zeros((mesh.n_nodes, 2))
    for a, b, ra, rb in zip(top[:-1], top[1:], x[:-1], x[1:]):
        if rb > radius * (1 + 1e-9):
            break
        if axisymmetric:
            fa, fb = 2 * np.pi * (rb - ra) * (2 * ra + rb) / 6, 2 * np.pi * (rb - ra) * (ra + 2 * rb) / 6
        else:
            fa = fb = (rb - ra) / 2
        f[a, 1] -= pressure * fa
        f[b, 1] -= pressure * fb
    if not f.any():
        raise ValueError(f"static: no top-layer edge lies within {radius!r} m of the axis")
    return f


def static_pressure(scene: Scene, preset: str | MeshSpec, *, pressure: float, radius: float,
                    element: str = fem.DEFAULT_ELEMENT) -> tuple[Mesh, np.ndarray, np.ndarray]:
    """(full mesh, displacement (N, 2) [m], von Mises (N,) [Pa]) of the panel of ``scene`` at ``preset`` under a
    uniform ``pressure`` [Pa] within ``radius`` [m] (:func:`pressure_loads`), the ball's nodes held."""
    mesh = build_mesh(scene, preset)
    youngs, poisson, density = _material_arrays(scene, mesh.cell_part)
    ke, _, _ = fem.element_matrices(mesh.points, mesh.cells, youngs, poisson, density, analysis=scene.analysis,
                                    element=element)
    k = fem.assemble_csr(mesh.cells, ke, mesh.n_nodes).tocsc()
    fixed = mesh.fixed.copy()
    fixed[mesh.node_part == 0] = True          # the ball is held (it touches nothing)
    free = np.flatnonzero(~fixed.ravel())
    f = pressure_loads(mesh, pressure, radius, scene.analysis == "axisymmetric").ravel()
    u = np.zeros(2 * mesh.n_nodes)
    u[free] = spla.spsolve(k[free][:, free], f[free])
    u = u.reshape(-1, 2)
    return mesh, u, recovered_von_mises(u[None], scene, mesh, element)[0]
