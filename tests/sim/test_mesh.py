"""Meshes: valid elements for every preset and design, shared topology, contact resolution,
node sets, conformity and the region-of-interest crop."""
from __future__ import annotations

import functools

import numpy as np
import pytest

from pcmgn_jax.scene import default_scene
from pcmgn_jax.sim import fem, mesh as M

MESH_PRESETS_TESTED = ("tiny", "cpu", "paper")
DESIGNS = [(40e-6, 40e-6), (40e-6, 160e-6), (100e-6, 100e-6), (160e-6, 40e-6), (160e-6, 160e-6)]


@functools.lru_cache(maxsize=None)
def _mesh(preset, t1=100e-6, t2=100e-6, analysis="axisymmetric"):
    return M.build_mesh(default_scene(t_oca1=t1, t_oca2=t2, analysis=analysis), preset)


def _materials(scene, cell_part):
    props = np.array([[scene.ball.youngs, scene.ball.poisson, scene.ball.density]]
                     + [[lay.youngs, lay.poisson, lay.density] for lay in scene.layers])
    return props[cell_part].T


def _corner_jacobians(points, cells):
    """det J at the four corners of every quad (E,4): all > 0 <=> every quad strictly convex
    and counter-clockwise (stricter than fem's Gauss-point check)."""
    xy = points[cells]
    dets = []
    for xi, eta in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        _, dn = fem.shape_functions(xi, eta)
        jac = np.einsum("ak,ekb->eab", dn, xy)
        dets.append(np.linalg.det(jac))
    return np.stack(dets, axis=1)


def _interior_angles(points, cells):
    xy = points[cells]
    a = np.roll(xy, 1, axis=1) - xy
    b = np.roll(xy, -1, axis=1) - xy
    cos = np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def _edges(cells):
    e = np.stack([cells, np.roll(cells, -1, axis=1)], axis=-1).reshape(-1, 2)
    return np.unique(np.sort(e, axis=1), axis=0, return_counts=True)


# ---- element validity and topology -------------------------------------------------------------
@pytest.mark.parametrize("preset", MESH_PRESETS_TESTED)
@pytest.mark.parametrize("design", DESIGNS)
def test_jacobians_positive_for_presets_and_designs(preset, design):
    scene = default_scene(t_oca1=design[0], t_oca2=design[1])
    mesh = _mesh(preset, *design)
    youngs, nu, rho = _materials(scene, mesh.cell_part)
    for analysis in ("axisymmetric", "plane_strain"):
        fem.element_matrices(mesh.points, mesh.cells, youngs, nu, rho, analysis=analysis)  # raises otherwise
    assert _corner_jacobians(mesh.points, mesh.cells).min() > 0


@pytest.mark.parametrize("preset", MESH_PRESETS_TESTED)
def test_topology_identical_across_designs(preset):
    ref = _mesh(preset)
    for design in DESIGNS:
        m = _mesh(preset, *design)
        assert m.points.shape == ref.points.shape
        for name in ("cells", "cell_part", "node_part", "node_type", "fixed", "ball_surface", "panel_top"):
            np.testing.assert_array_equal(getattr(m, name), getattr(ref, name), err_msg=name)
        # only heights inside/below the design layers move; the ball moves rigidly with the top
        assert not np.array_equal(m.points, ref.points) or design == (100e-6, 100e-6)
        np.testing.assert_allclose(m.points[:, 0], ref.points[:, 0], rtol=0, atol=1e-15)


@pytest.mark.parametrize("preset", MESH_PRESETS_TESTED)
def test_mesh_is_conforming_without_duplicate_nodes(preset):
    mesh = _mesh(preset)
    _, counts = _edges(mesh.cells)
    assert counts.max() == 2  # every edge shared by at most two quads (no T-junction overlap)
    used = np.unique(mesh.cells)
    np.testing.assert_array_equal(used, np.arange(mesh.n_nodes))  # no orphan nodes
    # two bodies (ball, panel), each simply connected: Euler characteristic V - E + F = 2
    n_edges = len(_edges(mesh.cells)[0])
    assert mesh.n_nodes - n_edges + len(mesh.cells) == 2
    # no coincident nodes inside a body (a crack would still pass the edge count)
    from scipy.spatial import cKDTree
    for body in (mesh.node_part == 0, mesh.node_part != 0):
        pts = mesh.points[body]
        assert not cKDTree(pts).query_pairs(1e-3 * M.mesh_spec(preset).h_contact)


@pytest.mark.parametrize("preset", MESH_PRESETS_TESTED)
def test_geometry_areas(preset):
    scene = default_scene()
    mesh = _mesh(preset)
    xy = mesh.points[mesh.cells]
    area = 0.5 * np.sum(xy[..., 0] * np.roll(xy[..., 1], -1, 1) - np.roll(xy[..., 0], -1, 1) * xy[..., 1], 1)
    ball = mesh.cell_part == 0
    assert area[~ball].sum() == pytest.approx(scene.half_width * scene.panel_thickness, rel=1e-12)
    # the polygonal half disk is inscribed in the circle: slightly smaller, by O(h^2/R^2) at most
    half_disk = 0.5 * np.pi * scene.ball.radius**2
    assert 0.99 * half_disk < area[ball].sum() < half_disk
    for li, layer in enumerate(scene.layers, start=1):
        cells = mesh.cell_part == li
        assert area[cells].sum() == pytest.approx(scene.half_width * layer.thickness, rel=1e-9), layer.name


def test_element_angles():
    """Documents a mesh-quality defect (see report): the O-grid core is the rectangle
    [0, 0.7R] x [-0.3R, 0.3R], so its lower-right corner (0.7R, -0.3R) is joined almost
    vertically to the arc point at -45 deg (0.707R, -0.707R); the right patch's first element
    there has a ~179 deg corner (Jacobian ratio ~0.03). It is far from the contact and does
    not set the stable step, so results are not wrong, but the docstring's promise of
    90-135 deg corners does not hold. Panel elements are rectangles (90 deg)."""
    for preset in MESH_PRESETS_TESTED:
        mesh = _mesh(preset)
        ang = _interior_angles(mesh.points, mesh.cells)
        panel = mesh.cell_part != 0
        np.testing.assert_allclose(ang[panel], 90.0, atol=1e-6)
        assert ang.max() < 180.0
        # corners near the contact zone (ball within 2 fine radii of the pole) are well shaped
        spec = M.mesh_spec(preset)
        pole = mesh.points[mesh.ball_surface[0]]
        near = (np.linalg.norm(mesh.points[mesh.cells] - pole, axis=-1).max(1) < 2 * spec.fine_radius) & ~panel
        assert near.any() and ang[near].max() < 135.0 and ang[near].min() > 45.0


def test_ball_corner_angles_below_170_degrees():
    mesh = _mesh("tiny")
    assert _interior_angles(mesh.points, mesh.cells).max() < 150.0


# ---- resolution at the contact -----------------------------------------------------------------
def _edge_lengths(points, cells):
    return np.linalg.norm(points[cells] - points[np.roll(cells, -1, axis=1)], axis=-1)


@pytest.mark.parametrize("preset", MESH_PRESETS_TESTED)
def test_element_size_at_contact(preset):
    spec = M.mesh_spec(preset)
    h = spec.h_contact
    mesh = _mesh(preset)
    p, c = mesh.points, mesh.cells
    lengths = _edge_lengths(p, c)
    tol = 1 + 1e-9
    # cells touching the ball pole and the cover-glass top node on the axis
    for node in (mesh.ball_surface[0], mesh.panel_top[0]):
        touching = np.any(c == node, axis=1)
        assert touching.sum() >= 1
        assert lengths[touching].max() <= h * tol
    # every ball-surface and CG-top segment inside the fine radius, and the cells that carry it
    for surf in (mesh.ball_surface, mesh.panel_top):
        inside = surf[p[surf, 0] <= spec.fine_radius * tol]
        seg = np.stack([inside[:-1], inside[1:]], 1)
        assert len(seg) >= spec.fine_radius / h * 0.9
        assert np.linalg.norm(p[seg[:, 1]] - p[seg[:, 0]], axis=1).max() <= h * tol
        for a, b in seg:
            carrier = np.any(c == a, 1) & np.any(c == b, 1)
            assert carrier.sum() == 1
            assert lengths[carrier].max() <= h * tol
    # top layer rows near the axis
    cg = (mesh.cell_part == 1) & (p[c, 0].max(1) <= spec.fine_radius * tol)
    assert lengths[cg].max() <= h * tol


def test_paper_preset_resolves_10_um():
    mesh = _mesh("paper")
    assert M.mesh_spec("paper").h_contact <= 10e-6
    p = mesh.points
    near = mesh.ball_surface[p[mesh.ball_surface, 0] <= 0.2e-3]
    assert np.diff(p[near, 0]).max() <= 10e-6 * (1 + 1e-9)
    near = mesh.panel_top[p[mesh.panel_top, 0] <= 0.2e-3]
    assert np.diff(p[near, 0]).max() <= 10e-6 * (1 + 1e-9)
    # the Hertz contact radius for the default impact is ~230 um: >= 20 elements across it
    assert np.sum(p[mesh.panel_top, 0] <= 230e-6) >= 20


# ---- node sets ---------------------------------------------------------------------------------
@pytest.mark.parametrize("preset", MESH_PRESETS_TESTED)
@pytest.mark.parametrize("analysis", ["axisymmetric", "plane_strain"])
def test_node_sets(preset, analysis):
    scene = default_scene(analysis=analysis)
    mesh = _mesh(preset, analysis=analysis)
    p = mesh.points
    n_parts = len(scene.part_names)
    bottom = np.abs(p[:, 1]) < 1e-15
    axis = np.abs(p[:, 0]) == 0.0
    assert bottom.sum() == len(mesh.panel_top)  # structured panel: same columns top and bottom
    np.testing.assert_array_equal(mesh.fixed[:, 1], bottom)
    np.testing.assert_array_equal(mesh.fixed[:, 0], bottom | axis)
    # axis nodes: panel column and ball column, x fixed, y free (except the plate corner)
    panel = mesh.node_part != 0
    assert axis[~panel].sum() >= 3
    assert axis[panel].sum() == len(np.unique(p[panel, 1]))  # one axis node per panel row
    assert np.all(mesh.fixed[axis, 0]) and not np.any(mesh.fixed[axis & ~bottom, 1])
    assert np.all(p[:, 0] >= 0)
    # node types: fixed bottom nodes get the extra type, everything else its part
    np.testing.assert_array_equal(mesh.node_type[bottom], n_parts)
    np.testing.assert_array_equal(mesh.node_type[~bottom], mesh.node_part[~bottom])
    assert set(np.unique(mesh.node_part)) == set(range(n_parts))
    # bottom nodes belong to the plate
    assert np.all(mesh.node_part[bottom] == n_parts - 1)


@pytest.mark.parametrize("preset", MESH_PRESETS_TESTED)
def test_ball_surface_and_panel_top(preset):
    scene = default_scene()
    mesh = _mesh(preset)
    p = mesh.points
    R = scene.ball.radius
    bs = mesh.ball_surface
    ball_nodes = np.flatnonzero(mesh.node_part == 0)
    assert np.isin(bs, ball_nodes).all()
    # sorted by x, starting at the pole on the axis, which is the lowest ball point
    assert p[bs[0], 0] == 0.0
    assert np.all(np.diff(p[bs, 0]) > 0)
    assert p[bs[0], 1] == pytest.approx(p[ball_nodes, 1].min(), abs=1e-15)
    assert p[bs[0], 1] == pytest.approx(scene.panel_thickness + scene.ball.gap, rel=1e-12)
    # on the sphere, lower surface up to 45 degrees
    center = np.array([0.0, scene.panel_thickness + scene.ball.gap + R])
    np.testing.assert_allclose(np.linalg.norm(p[bs] - center, axis=1), R, rtol=1e-9)
    assert p[bs[-1], 0] > R * np.sqrt(0.5)  # the contact arc runs past -45 degrees
    # panel top: the top layer's upper face, sorted by x from the axis to the edge
    pt = mesh.panel_top
    np.testing.assert_allclose(p[pt, 1], scene.panel_thickness, rtol=1e-12)
    assert p[pt[0], 0] == 0.0 and p[pt[-1], 0] == pytest.approx(scene.half_width)
    assert np.all(np.diff(p[pt, 0]) > 0)
    assert np.all(mesh.node_part[pt] == 1)
    # every panel node at the top height is in panel_top
    top = (mesh.node_part != 0) & (np.abs(p[:, 1] - scene.panel_thickness) < 1e-12)
    assert top.sum() == len(pt)


@pytest.mark.parametrize("preset", ["tiny", "paper"])
def test_parts_follow_layers(preset):
    scene = default_scene(t_oca1=60e-6, t_oca2=140e-6)
    mesh = _mesh(preset, 60e-6, 140e-6)
    p, c = mesh.points, mesh.cells
    tops = scene.panel_thickness - np.concatenate([[0.0], np.cumsum([lay.thickness for lay in scene.layers])])
    for li, layer in enumerate(scene.layers, start=1):
        ys = p[c[mesh.cell_part == li], 1]
        eps = 1e-12
        assert ys.max() <= tops[li - 1] + eps and ys.min() >= tops[li] - eps, layer.name
        n = M.mesh_spec(preset).layer_elems.get(layer.name)
        if n is not None:
            rows = len(np.unique(np.round(ys.mean(axis=1), 12)))
            assert rows == n, layer.name
    # interface nodes take the stiffer neighbour's part (CG 77 GPa over OCA1 10 MPa)
    cg_oca = np.abs(p[:, 1] - tops[1]) < 1e-12
    assert np.all(mesh.node_part[cg_oca & (mesh.node_part != 0)] == 1)


def test_unknown_preset_and_missing_design_counts():
    with pytest.raises(ValueError, match="preset"):
        M.build_mesh(default_scene(), "huge")
    spec = M.with_spec("tiny", layer_elems={"CG": 2})  # OCA1/OCA2 counts missing
    with pytest.raises(ValueError, match="OCA1"):
        M.build_mesh(default_scene(), spec)


# ---- region of interest ------------------------------------------------------------------------
@pytest.mark.parametrize("preset", MESH_PRESETS_TESTED)
def test_crop_roi_consistent(preset):
    spec = M.mesh_spec(preset)
    full = _mesh(preset)
    sub, node_map = M.roi(full, preset)
    assert sub.n_nodes == len(node_map) < full.n_nodes
    assert np.all(np.diff(node_map) > 0)
    np.testing.assert_array_equal(sub.points, full.points[node_map])
    for name in ("node_part", "node_type", "fixed"):
        np.testing.assert_array_equal(getattr(sub, name), getattr(full, name)[node_map], err_msg=name)
    assert sub.cells.min() == 0 and sub.cells.max() == sub.n_nodes - 1
    np.testing.assert_array_equal(np.unique(sub.cells), np.arange(sub.n_nodes))
    # every sub cell is a full cell (same node order, same part)
    full_rows = {tuple(row): i for i, row in enumerate(full.cells)}
    idx = np.array([full_rows[tuple(row)] for row in node_map[sub.cells]])
    np.testing.assert_array_equal(sub.cell_part, full.cell_part[idx])
    assert _corner_jacobians(sub.points, sub.cells).min() > 0
    # bounds
    assert sub.points[:, 0].max() <= spec.roi_x * (1 + 1e-9)
    ball = sub.node_part == 0
    assert sub.points[ball, 1].max() <= full.points[full.ball_surface, 1].min() + spec.roi_ball_height * (1 + 1e-9)
    # node sets: order kept, contact surfaces start at the axis
    np.testing.assert_array_equal(node_map[sub.ball_surface], full.ball_surface[:len(sub.ball_surface)])
    np.testing.assert_array_equal(node_map[sub.panel_top], full.panel_top[:len(sub.panel_top)])
    assert full.points[full.ball_surface[len(sub.ball_surface) - 1], 0] <= spec.roi_x
    assert len(sub.ball_surface) >= 2 and len(sub.panel_top) >= 2
    assert sub.part_names == full.part_names
    # all parts are in the ROI (the OLED stress is the design objective)
    assert set(np.unique(sub.cell_part)) == set(range(len(full.part_names)))


def test_paper_roi_size():
    full = _mesh("paper")
    sub, _ = M.roi(full, "paper")
    # issue 2: the graph region has at least 2,000 nodes (paper: 2.4-3.1k of 11.5-14.4k)
    assert sub.n_nodes >= 2000, sub.n_nodes
    print(f"paper preset: full mesh {full.n_nodes} nodes, ROI {sub.n_nodes} nodes")


def test_crop_roi_explicit_and_empty():
    full = _mesh("tiny")
    sub, node_map = M.crop_roi(full, roi_x=0.3e-3, roi_ball_height=0.2e-3)
    assert sub.points[:, 0].max() <= 0.3e-3 * (1 + 1e-9)
    assert sub.n_nodes < M.roi(full, "tiny")[0].n_nodes
    with pytest.raises(ValueError, match="no cell"):
        M.crop_roi(full, roi_x=1e-9, roi_ball_height=1e-9)


def test_a_family_mesh_pinned_at_its_design():
    """pinned_spec: the same mesh at the scene, one topology for thicker layers (where the family mesh's own
    element counts would change), so a thickness derivative has a mesh to move."""
    from pcmgn_jax.data.designs import FAMILIES
    from pcmgn_jax.scene import default_scene, with_parameters
    from pcmgn_jax.sim.mesh import build_mesh, mesh_spec, pinned_spec
    fam = FAMILIES["family_tiny"]
    scene = with_parameters(fam.base(default_scene()), {"OCA1": 120e-6, "POL": 40e-6})
    spec = pinned_spec(scene, "family_tiny")
    a, b = build_mesh(scene, "family_tiny"), build_mesh(scene, spec)
    assert np.array_equal(a.cells, b.cells) and np.array_equal(a.points, b.points)
    thicker = with_parameters(scene, {"OCA1": 180e-6})
    assert build_mesh(thicker, "family_tiny").n_nodes != a.n_nodes          # the family's own rule re-meshes
    assert np.array_equal(build_mesh(thicker, spec).cells, a.cells)          # the pinned one keeps the topology
    assert pinned_spec(scene, "tiny") is mesh_spec("tiny")          # a preset of fixed counts is returned as it is
