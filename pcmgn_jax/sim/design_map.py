"""The region-of-interest mesh as a function of the design (the design layers' thicknesses).

At a fixed mesh preset every design has the same topology (``MeshSpec.layer_elems`` fixes the elements
through each layer), and a layer's node heights are uniform in its thickness, so the reference
coordinates are an *affine* function of the design: ``points(d) = points(d0) + sum_k J_k (d - d0)_k``.
:class:`DesignMap` measures ``J`` once by finite differences of :func:`build_mesh` (exact up to
rounding for an affine map, checked at construction) and then gives the mesh of any design as a
differentiable JAX/NumPy expression: the optimiser takes ``jax`` derivatives through it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pcmgn_jax.scene import Scene
from pcmgn_jax.sim.mesh import Mesh, MeshSpec, build_mesh, roi


def design_mesh(scene: Scene, design, preset: str | MeshSpec, *, crop: bool = True) -> Mesh:
    """The preset's region-of-interest mesh of ``scene`` at ``design`` (D,) [m] (the full solver mesh when
    ``crop`` is False)."""
    full = build_mesh(scene.with_design(*np.asarray(design, float)), preset)
    return roi(full, preset)[0] if crop else full


@dataclass(frozen=True)
class DesignMap:
    """points(d) = p0 + tensordot(d - d0, jac, 1): (N, 2) [m] for a design d (D,) [m].

    p0 (N, 2) [m] at d0 (D,) [m]; jac (D, N, 2) [m/m]; ``mesh`` is the mesh at d0 (topology, parts).
    """

    mesh: Mesh
    d0: np.ndarray
    p0: np.ndarray
    jac: np.ndarray

    @classmethod
    def build(cls, scene: Scene, preset: str | MeshSpec, d0=None, *, step: float = 10e-6,
              check_tol: float = 1e-12, crop: bool = True) -> "DesignMap":
        """Finite-difference the mesh around ``d0`` (default: the scene's design) with ``step`` [m] and
        check the map is affine (the mesh at d0 + 2 step along every axis, predicted to ``check_tol`` [m]);
        ValueError when a design changes the topology or the map is not affine. ``crop``: the region of
        interest (the surrogates' mesh) or, False, the full solver mesh (the differentiable solver's)."""
        d0 = np.asarray(scene.design if d0 is None else d0, float)
        base = design_mesh(scene, d0, preset, crop=crop)
        cols = []
        for k in range(len(d0)):
            e = np.zeros_like(d0)
            e[k] = step
            cols.append((cls._points(scene, d0 + e, preset, base, crop) - base.points) / step)
        dm = cls(mesh=base, d0=d0, p0=base.points.copy(), jac=np.stack(cols))
        probe = d0 + 2 * step
        err = np.abs(cls._points(scene, probe, preset, base, crop) - dm.points(probe)).max()
        if err > check_tol:
            raise ValueError(f"design map: the mesh is not affine in the design (error {err:.3e} m at "
                             f"{probe * 1e6} µm); gradients through the mesh would be wrong")
        return dm

    @staticmethod
    def _points(scene, d, preset, base: Mesh, crop: bool) -> np.ndarray:
        m = design_mesh(scene, d, preset, crop=crop)
        if m.n_nodes != base.n_nodes or not np.array_equal(m.cells, base.cells):
            raise ValueError(f"design {np.asarray(d) * 1e6} µm gives another topology than "
                             f"{np.asarray(base.points.shape)} nodes at the reference design")
        return m.points

    def points(self, design):
        """(N, 2) [m] (or (B, N, 2) for designs (B, D)); jax arrays in -> jax out (differentiable)."""
        if isinstance(design, np.ndarray) or np.isscalar(design) or isinstance(design, (list, tuple)):
            d = np.asarray(design, float)
            return self.p0 + np.tensordot(d - self.d0, self.jac, axes=(-1, 0))
        import jax.numpy as jnp
        return jnp.asarray(self.p0) + jnp.tensordot(design - jnp.asarray(self.d0), jnp.asarray(self.jac),
                                                    axes=(-1, 0))
