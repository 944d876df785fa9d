"""Mesh geometry rules shared by the simulator, the dataset, the graph builder, training and evaluation.

One home for each rule (host-side NumPy only; the package imports nothing else from pcmgn_jax). Modules:
:mod:`~pcmgn_jax.geometry.sides` (sides, normals, surfaces, interface parts), :mod:`~pcmgn_jax.geometry.roi`
(the region-of-interest crop), :mod:`~pcmgn_jax.geometry.boundary` (contact-pair boundary nodes); every
name is re-exported here:

- :func:`cell_sides` -- the sides of every cell, as (a, b, owner) with a -> b in the cell's corner order.
- :func:`quad_sides` -- the unique undirected sides of (E, 4) quads (the graph's mesh edges).
- :func:`boundary_sides` -- sides used by exactly one of the given cells (the outline of a part).
- :func:`outward_normals` -- unit outward normals of sides, from the owning cell's signed area
  (clockwise and counter-clockwise cells both work).
- :func:`surface_nodes` -- nodes of a part on boundary sides whose outward normal points up or down.
- :func:`stiffest_adjacent_part` -- an interface node takes the part of its stiffest adjacent cell.
- :func:`roi_crop` -- the region-of-interest crop rule (contact zone, radius, depth, ball height) for any
  quad mesh; :func:`put_back` returns cropped nodal fields to full-size arrays.
- :func:`boundary_nodes` / :func:`roi_boundary_nodes` -- ball-bottom and cover-glass-top nodes of the
  reference mesh, with the penetration fit interval.

Shapes: ``points`` (N, 2) [m], ``cells`` (E, k) node indices (k = 4 for quads; a collapsed quad repeats a
node), ``cell_part`` (E,) part ids.
"""
from __future__ import annotations

from pcmgn_jax.geometry.boundary import (
    BoundaryNodes,
    boundary_nodes,
    roi_boundary_nodes,
)
from pcmgn_jax.geometry.roi import (
    ROI_REL_TOL,
    RoiCrop,
    RoiCropError,
    put_back,
    roi_crop,
)
from pcmgn_jax.geometry.sides import (
    boundary_sides,
    cell_sides,
    outward_normals,
    quad_sides,
    stiffest_adjacent_part,
    surface_nodes,
)

__all__ = [
    "ROI_REL_TOL",
    "BoundaryNodes",
    "RoiCrop",
    "RoiCropError",
    "boundary_nodes",
    "boundary_sides",
    "cell_sides",
    "outward_normals",
    "put_back",
    "quad_sides",
    "roi_boundary_nodes",
    "roi_crop",
    "stiffest_adjacent_part",
    "surface_nodes",
]
