"""Structured 2D quad meshes of the half model (ball + bonded panel layers), and ROI cropping.

Coordinates [m]: x >= 0 is the radius (axisymmetric) or the half width (plane strain), the
symmetry axis is x = 0, y is the height with the plate bottom at y = 0. The ball is a half
disk meshed with the elliptical square-to-disk map, so its bottom pole (the contact point)
sits in the middle of a well-shaped, graded patch. Element counts per layer are fixed by the
:class:`MeshSpec`, so every design (OCA thicknesses) of a scene has the same topology -- except in the
scene-family presets (``thickness_elems``), where the layers not listed in ``layer_elems`` get
ceil(thickness / h_layer) elements: there the node count changes with the layer thicknesses (and, as in
every preset, with the ball radius, whose arc is meshed at the contact size).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from pcmgn_jax import geometry
from pcmgn_jax.presets import PRESETS
from pcmgn_jax.scene import Scene


@dataclass(frozen=True)
class MeshSpec:
    """Mesh resolution. Lengths in metres.

    h_contact:    element size at the contact (ball pole, cover-glass top near the axis)
    fine_radius:  radial extent of the uniform fine zone around the axis
    fine_depth:   depth of the uniform fine zone inside the ball below its surface
    growth:       geometric growth ratio of element sizes outside the fine zone
    layer_elems:  elements through the thickness of each layer (by name); fixed per preset
                  so all designs share one topology. Missing names: ceil(t / h_layer), and
                  for the bottom layer uniform h_layer to fine_depth then growth.
    h_layer:      target through-thickness size for layers not listed in layer_elems
    bottom_growth: growth ratio (downwards) of the bottom (thick) layer's element sizes
    roi_x:        region-of-interest radius for the graph (panel and ball nodes x <= roi_x);
                  3 mm covers the design objective (OLED stress at x < 3 mm)
    roi_ball_height: ball nodes with y <= (ball bottom + this) are kept in the ROI
    thickness_elems: layers missing from layer_elems (design layers included) get
                  ceil(thickness / h_layer) elements: the topology follows the design (scene families)
    """

    h_contact: float = 10e-6
    fine_radius: float = 0.6e-3
    fine_depth: float = 0.1e-3
    growth: float = 1.15
    layer_elems: Mapping[str, int] = field(default_factory=lambda: {
        "CG": 10, "OCA1": 6, "POL": 5, "OCA2": 6, "OLED": 3, "PLATE": 12})
    h_layer: float = 10e-6
    bottom_growth: float = 1.3
    roi_x: float = 1.5e-3
    roi_ball_height: float = 0.8e-3
    thickness_elems: bool = False


MESH_PRESETS: dict[str, MeshSpec] = {name: MeshSpec(**p.mesh) for name, p in PRESETS.items()}
"""Each preset's mesh (its ``mesh`` settings in :data:`pcmgn_jax.presets.PRESETS`)."""


def mesh_spec(preset: str | MeshSpec) -> MeshSpec:
    """A preset's mesh, or a mesh by name (:func:`named_spec`: ``cpu_fine``, ``PRESET@F``, ``PRESET@F:ZONE``)."""
    if isinstance(preset, MeshSpec):
        return preset
    if preset not in MESH_PRESETS and ("@" in preset or preset == "cpu_fine"):
        return mesh_spec(named_spec(preset))
    if preset not in MESH_PRESETS:
        raise ValueError(f"unknown mesh preset {preset!r}; choose one of {sorted(MESH_PRESETS)}")
    return MESH_PRESETS[preset]


def pinned_spec(scene: Scene, preset: str | MeshSpec) -> MeshSpec:
    """``preset``'s mesh with every layer's element count fixed at ``scene``'s: the same mesh at ``scene``,
    and one topology for thicknesses near it (a ``thickness_elems`` family mesh sizes its layers by their
    thickness, so its topology follows the design; a derivative in a thickness is of the pinned mesh)."""
    spec, bottom = mesh_spec(preset), scene.layers[-1].name
    if not spec.thickness_elems:
        return spec
    pinned = {layer.name: spec.layer_elems.get(layer.name, n)
              for layer, n in zip(scene.layers, _layer_counts(scene, spec))
              if layer.name != bottom or layer.name in spec.layer_elems}   # in the scene's order
    return dataclasses.replace(spec, layer_elems=pinned, thickness_elems=False)


@dataclass(frozen=True)
class Mesh:
    """A quad mesh with part ids and node sets.

    points (N,2) float64 [m]; cells (E,4) int64 counter-clockwise; cell_part (E,) int32;
    node_part (N,) int32 (interface nodes take the stiffer layer's part); node_type (N,) int32
    (= node_part, or n_parts for fixed nodes); fixed (N,2) bool per-dof Dirichlet mask
    (plate bottom: both; symmetry axis: x); ball_surface / panel_top: node indices sorted
    by x; part_names indexed by part id.
    """

    points: np.ndarray
    cells: np.ndarray
    cell_part: np.ndarray
    node_part: np.ndarray
    node_type: np.ndarray
    fixed: np.ndarray
    ball_surface: np.ndarray
    panel_top: np.ndarray
    part_names: tuple[str, ...]

    @property
    def n_nodes(self) -> int:
        return int(self.points.shape[0])


def graded_coords(length: float, h: float, fine: float, growth: float) -> np.ndarray:
    """Monotone 1D node coordinates on [0, length] [m]: uniform size ``h`` up to ``fine``,
    then sizes growing by ``growth`` per element; the last element is merged if it would be
    shorter than half its predecessor."""
    if length <= 0 or h <= 0:
        raise ValueError(f"graded_coords: length and h must be > 0, got {length}, {h}")
    xs = [0.0]
    size = h
    while xs[-1] < length - 1e-12 * length:
        if xs[-1] + 1e-12 >= fine:
            size *= growth
        xs.append(xs[-1] + size)
    xs = np.asarray(xs)
    xs[-1] = length
    if len(xs) > 2 and (xs[-1] - xs[-2]) < 0.5 * (xs[-2] - xs[-3]):
        xs = np.delete(xs, -2)
    # stretch uniformly-graded tail so the end lands on length exactly
    return xs


def _layer_counts(scene: Scene, spec: MeshSpec) -> list[int]:
    counts = []
    for li, layer in enumerate(scene.layers):
        n = spec.layer_elems.get(layer.name)
        if n is None and li == len(scene.layers) - 1:
            counts.append(0)  # graded automatically in _panel_y
            continue
        if n is None:
            if layer.name in scene.design_layers and not spec.thickness_elems:
                raise ValueError(
                    f"mesh: design layer {layer.name!r} needs a fixed element count in "
                    "MeshSpec.layer_elems (the topology must not depend on the design)")
            n = max(1, math.ceil(layer.thickness / spec.h_layer - 1e-9))
        if n < 1:
            raise ValueError(f"mesh: layer_elems[{layer.name!r}] must be >= 1, got {n}")
        counts.append(int(n))
    return counts


def _panel_y(scene: Scene, spec: MeshSpec) -> tuple[np.ndarray, np.ndarray]:
    """Node heights [m] of the panel and the layer index of each element row (0 = top layer)."""
    counts = _layer_counts(scene, spec)
    ys: list[float] = []
    row_layer: list[int] = []
    top = scene.panel_thickness
    y = top
    ys.append(y)
    n_layers = len(scene.layers)
    for li, (layer, n) in enumerate(zip(scene.layers, counts)):
        t = layer.thickness
        if li == n_layers - 1 and layer.name not in spec.layer_elems:
            # thick bottom block: uniform h_layer near its top, then geometric growth
            sizes = np.diff(graded_coords(t, spec.h_layer, spec.fine_depth, spec.growth))
        elif li == n_layers - 1 and n > 1 and spec.bottom_growth != 1.0:
            g = spec.bottom_growth
            sizes = g ** np.arange(n)
            sizes = sizes / sizes.sum() * t
        else:
            sizes = np.full(n, t / n)
        for s in sizes:
            y -= s
            ys.append(y)
            row_layer.append(li)
    ys = np.asarray(ys)
    ys[-1] = 0.0
    return ys[::-1].copy(), np.asarray(row_layer[::-1])


def _stretched(depth: float, h: float, n: int) -> np.ndarray:
    """Distances [m] from the outer surface of n+1 nodes across ``depth``: the first element
    is ``h`` and sizes grow geometrically (ratio found by bisection; < 1 if depth < n h)."""
    lo, hi = 0.5, 3.0
    for _ in range(200):
        r = 0.5 * (lo + hi)
        total = h * n if abs(r - 1) < 1e-12 else h * (r**n - 1) / (r - 1)
        lo, hi = (r, hi) if total < depth else (lo, r)
    d = np.concatenate([[0.0], np.cumsum(h * r ** np.arange(n))])
    return d * (depth / d[-1])


def _patch(c_pts: np.ndarray, a_pts: np.ndarray, h: float, n_rad: int):
    """Structured patch between an inner curve C (n_t,2) and an outer arc A (n_t,2) with
    n_rad elements along each C->A line, the one at the arc of size h. Returns points
    (n_rad+1, n_t, 2) flattened, and CCW cells; row n_rad is the arc."""
    depth = np.linalg.norm(a_pts - c_pts, axis=1)
    frac = np.stack([1.0 - _stretched(d, h, n_rad)[::-1] / d for d in depth], axis=1)  # (n_r, n_t)
    pts = c_pts[None] + frac[..., None] * (a_pts - c_pts)[None]
    n_r, n_t = n_rad + 1, c_pts.shape[0]
    idx = np.arange(n_r * n_t).reshape(n_r, n_t)
    cells = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], axis=-1).reshape(-1, 4)
    return pts.reshape(-1, 2), cells


def _ccw(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    xy = points[cells]
    area = 0.5 * np.sum(xy[..., 0] * np.roll(xy[..., 1], -1, 1) - np.roll(xy[..., 0], -1, 1) * xy[..., 1], 1)
    return np.where((area < 0)[:, None], cells[:, ::-1], cells)


def _ball_mesh(scene: Scene, spec: MeshSpec, y_bottom: float):
    """Half-disk O-grid: a core rectangle [0, 0.7R] x [-0.3R, 0.3R] and three patches (bottom,
    right, top) between the core and the arc. The arc is split at +-phi where the diagonal from
    each core corner meets it at 45 degrees, so patch corners stay near 90/135 degrees (a single
    mapped patch would put 180-degree corners on the arc and wreck the stable time step).
    The bottom patch carries the contact: its arc nodes are graded from the pole (h_contact over
    fine_radius, then growth) and its radial lines start with h_contact at the arc; its core-side
    nodes are uniform, so the mesh coarsens with depth and no thin column runs up the axis.
    Returns absolute points [m], CCW cells, and the bottom-arc (contact) node ids sorted by x."""
    from scipy.spatial import cKDTree

    R = scene.ball.radius
    s, b = 0.7 * R, 0.3 * R
    phi = math.acos((s - b) / (R * math.sqrt(2.0))) - math.pi / 4  # split angle below horizontal
    arc_b = R * (math.pi / 2 - phi)  # arc length of the bottom (and top) patch
    # arc spacing 5 % under h_contact: the radial lines fan out towards the (coarser) core, so the
    # elements just inside the surface are a few per cent wider than their arc edge
    tau = graded_coords(1.0, 0.95 * spec.h_contact / arc_b, spec.fine_radius / arc_b, spec.growth)
    uni = np.linspace(0.0, 1.0, len(tau))
    n_rad = len(graded_coords(R - b, spec.h_contact, spec.fine_depth, spec.growth)) - 1
    h = spec.h_contact
    last = (tau[-1] - tau[-2]) * arc_b
    n_side = max(2, math.ceil(2 * phi * R / last))
    sig = np.linspace(0.0, 1.0, n_side + 1)
    # bottom patch: core bottom edge (uniform) -> arc from the pole to -phi (graded)
    ang = tau * (math.pi / 2 - phi)
    pb, cb = _patch(np.stack([s * uni, np.full_like(uni, -b)], 1),
                    np.stack([R * np.sin(ang), -R * np.cos(ang)], 1), h, n_rad)
    # right patch: core right edge -> arc from -phi to +phi
    ang_r = -phi + sig * 2 * phi
    pr, cr = _patch(np.stack([np.full_like(sig, s), -b + 2 * b * sig], 1),
                    np.stack([R * np.cos(ang_r), R * np.sin(ang_r)], 1), h, n_rad)
    # top patch: core top edge -> arc from the top pole to +phi (both uniform)
    ang_t = uni * (math.pi / 2 - phi)
    pt, ct = _patch(np.stack([s * uni, np.full_like(uni, b)], 1),
                    np.stack([R * np.sin(ang_t), R * np.cos(ang_t)], 1), h, n_rad)
    # core
    cx, cy = np.meshgrid(s * uni, -b + 2 * b * sig, indexing="xy")
    pc = np.stack([cx.ravel(), cy.ravel()], 1)
    idx = np.arange(cx.size).reshape(cx.shape)
    cc = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], axis=-1).reshape(-1, 4)
    parts = [(pb, cb), (pr, cr), (pt, ct), (pc, cc)]
    pts = np.concatenate([p for p, _ in parts])
    offs = np.cumsum([0] + [len(p) for p, _ in parts[:-1]])
    cells = np.concatenate([c + o for (_, c), o in zip(parts, offs)])
    # merge coincident nodes on patch interfaces
    tree = cKDTree(pts)
    rep = np.arange(len(pts))
    for i, j in sorted(tree.query_pairs(1e-9 * R)):
        rep[j] = rep[i] if rep[i] < rep[j] else rep[j]
    for k in range(len(rep)):
        rep[k] = rep[rep[k]]
    uniq, inverse = np.unique(rep, return_inverse=True)
    pts = pts[uniq]
    cells = _ccw(pts, inverse[cells])
    surface_bottom = inverse[n_rad * len(tau) + np.arange(len(tau))]
    pts[:, 1] += y_bottom + R
    pts[np.abs(pts[:, 0]) < 1e-12 * R, 0] = 0.0
    return pts, cells, surface_bottom


def build_mesh(scene: Scene, preset: str | MeshSpec = "paper") -> Mesh:
    """Quad mesh of ball + panel for ``scene`` at the resolution of ``preset``."""
    spec = mesh_spec(preset)
    xs = graded_coords(scene.half_width, spec.h_contact, spec.fine_radius, spec.growth)
    ys, row_layer = _panel_y(scene, spec)
    nx, ny = len(xs), len(ys)
    PX, PY = np.meshgrid(xs, ys, indexing="xy")  # (ny, nx)
    panel_pts = np.stack([PX.ravel(), PY.ravel()], axis=1)
    pidx = np.arange(ny * nx).reshape(ny, nx)
    panel_cells = np.stack([pidx[:-1, :-1], pidx[:-1, 1:], pidx[1:, 1:], pidx[1:, :-1]],
                           axis=-1).reshape(-1, 4)
    panel_cell_part = np.repeat(row_layer + 1, nx - 1)  # part ids 1..n

    top = scene.panel_thickness
    ball_pts, ball_cells, ball_surface = _ball_mesh(scene, spec, top + scene.ball.gap)
    off = panel_pts.shape[0]
    points = np.concatenate([panel_pts, ball_pts], axis=0)
    cells = np.concatenate([panel_cells, ball_cells + off], axis=0).astype(np.int64)
    cell_part = np.concatenate([panel_cell_part, np.zeros(len(ball_cells), int)]).astype(np.int32)

    n_parts = len(scene.layers) + 1
    youngs = np.array([scene.ball.youngs] + [layer.youngs for layer in scene.layers])
    node_part = geometry.stiffest_adjacent_part(cells, cell_part, youngs, n_nodes=points.shape[0])
    fixed = np.zeros((points.shape[0], 2), bool)
    bottom = pidx[0, :]
    fixed[bottom, :] = True
    fixed[np.abs(points[:, 0]) < 1e-15, 0] = True
    node_type = node_part.copy()
    node_type[fixed.all(axis=1)] = n_parts
    panel_top = pidx[-1, :]
    return Mesh(points=points, cells=cells, cell_part=cell_part, node_part=node_part,
                node_type=node_type.astype(np.int32), fixed=fixed,
                ball_surface=(ball_surface + off).astype(np.int64),
                panel_top=panel_top.astype(np.int64), part_names=scene.part_names)


def crop_roi(mesh: Mesh, *, roi_x: float, roi_ball_height: float,
             depth: float = math.inf) -> tuple[Mesh, np.ndarray]:
    """Region-of-interest submesh by the one crop rule, :func:`pcmgn_jax.geometry.roi_crop`: cells whose
    nodes all lie at x <= roi_x [m] (the half model's contact axis is x = 0 in both analyses), ball cells
    also at y <= ball bottom + roi_ball_height [m], panel cells within ``depth`` [m] of the panel top
    (default: the full thickness). Returns (submesh, node_map) where ``node_map[i]`` is the full-mesh
    index of submesh node i; ball_surface / panel_top keep their order, cut to the kept nodes."""
    crop = geometry.roi_crop(mesh.points, mesh.cells, mesh.cell_part, radius=roi_x, depth=depth,
                             ball_height=roi_ball_height, analysis="axisymmetric", ball_part=0)
    node_map = crop.node_map
    inverse = np.full(mesh.n_nodes, -1, np.int64)
    inverse[node_map] = np.arange(len(node_map))

    def remap_sorted(ids: np.ndarray) -> np.ndarray:
        ids = ids[inverse[ids] >= 0]
        return inverse[ids]

    sub = Mesh(points=mesh.points[node_map], cells=crop.cells, cell_part=mesh.cell_part[crop.keep_cell],
               node_part=mesh.node_part[node_map], node_type=mesh.node_type[node_map],
               fixed=mesh.fixed[node_map], ball_surface=remap_sorted(mesh.ball_surface),
               panel_top=remap_sorted(mesh.panel_top), part_names=mesh.part_names)
    return sub, node_map


def roi(mesh: Mesh, preset: str | MeshSpec) -> tuple[Mesh, np.ndarray]:
    """The preset's region of interest of ``mesh`` (see :func:`crop_roi`)."""
    spec = mesh_spec(preset)
    return crop_roi(mesh, roi_x=spec.roi_x, roi_ball_height=spec.roi_ball_height)


def with_spec(preset: str | MeshSpec, **changes) -> MeshSpec:
    """A copy of a preset's MeshSpec with fields replaced."""
    return dataclasses.replace(mesh_spec(preset), **changes)


def refined(preset: str | MeshSpec, factor: float) -> MeshSpec:
    """A preset's MeshSpec refined by ``factor`` (2: every element about half as large; 0.5: coarsened): the
    contact and layer sizes h_contact, h_layer [m] divided by it, every ``layer_elems`` count multiplied by it
    (rounded up, at least 1), and the growth ratios taken to the power 1/factor, so the graded zones get
    ``factor`` times as many elements of 1/factor the size at the same place. The fine zones, the region of
    interest and the scene are unchanged (a mesh-refinement series of one preset)."""
    if not (math.isfinite(factor) and factor > 0):
        raise ValueError(f"mesh: refinement factor must be a finite number > 0, got {factor!r}")
    spec = mesh_spec(preset)
    return dataclasses.replace(
        spec, h_contact=spec.h_contact / factor, h_layer=spec.h_layer / factor,
        growth=spec.growth ** (1.0 / factor), bottom_growth=spec.bottom_growth ** (1.0 / factor),
        layer_elems={k: max(1, math.ceil(v * factor - 1e-9)) for k, v in spec.layer_elems.items()})


def named_spec(name: str) -> str | MeshSpec:
    """A mesh by name: a preset, ``cpu_fine``, ``PRESET@F``: the preset refined by the factor F
    (:func:`refined`; ``cpu@0.5`` coarsens), or ``PRESET@F:ZONE`` with only that zone refined
    (several joined by ``+``, e.g. ``cpu@0.5:layers+far``):
    ``far`` (the radial growth ratio to the power 1/F: the graded far field), ``layers`` (the element counts of
    the layers above the bottom one, x F) or ``plate`` (the bottom layer's count x F, its growth to the power 1/F)."""
    if "@" in name:
        preset, _, rest = name.partition("@")
        factor, _, zone = rest.partition(":")
        try:
            f = float(factor)
            full = refined(preset, f)
            base = mesh_spec(preset)
        except ValueError as err:
            raise ValueError(f"mesh {name!r}: {err}") from None
        bottom = list(base.layer_elems)[-1] if base.layer_elems else None
        overrides = {"far": {"growth": full.growth},
                     "layers": {"layer_elems": {k: full.layer_elems[k] if k != bottom else v
                                                for k, v in base.layer_elems.items()}},
                     "plate": {"bottom_growth": full.bottom_growth, "layer_elems": {
                         k: full.layer_elems[k] if k == bottom else v for k, v in base.layer_elems.items()}}}
        if not zone:
            return full
        spec = base
        for part in zone.split("+"):
            if part not in overrides:
                raise ValueError(f"mesh {name!r}: zone must be far, layers, plate or several joined by '+', "
                                 f"got {part!r}")
            kw = dict(overrides[part])
            if "layer_elems" in kw:   # a zone's counts on top of the others' (layers+plate: both)
                kw["layer_elems"] = {k: (v if kw["layer_elems"][k] != base.layer_elems[k] else spec.layer_elems[k])
                                     for k, v in kw["layer_elems"].items()}
            spec = with_spec(spec, **kw)
        return spec
    if name == "cpu_fine":
        base = mesh_spec("cpu")
        return with_spec("cpu", h_contact=base.h_contact / 2, h_layer=base.h_layer / 2,
                         layer_elems={k: 2 * v for k, v in base.layer_elems.items()})
    if name not in MESH_PRESETS:
        raise ValueError(f"mesh {name!r}: unknown mesh preset; one of {sorted(MESH_PRESETS)}, cpu_fine, PRESET@F or "
                         "PRESET@F:ZONE")
    return name
