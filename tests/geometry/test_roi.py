"""Region-of-interest crop of any quad mesh (pcmgn_jax.geometry.roi_crop), of trajectories
(pcmgn_jax.trajectory.crop_trajectory), of the generator's mesh (sim.mesh.crop_roi) and on import
(experiments.import_ansys --roi_*).

Hand-built meshes: a ball block above a layered panel, on structured grids, so the kept cells are known
by their (row, column) without evaluating the crop's inequalities again.
"""
from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pytest

from fixtures.ansys_files import write_cdb, write_results
from fixtures.helpers import FIXTURES, tensor_grid
from fixtures.synthetic import synthetic_trajectory
from pcmgn_jax import geometry
from pcmgn_jax.data import importers as imp
from pcmgn_jax.data.trajectory_io import read_trajectory
from pcmgn_jax.scene import Layer, Scene, default_scene
from pcmgn_jax.sim import mesh as M
from pcmgn_jax.trajectory import ROI_META_KEY, Trajectory, crop_trajectory

MM = 1e-3
# panel rows from the top: CG 2 x 0.05 mm, OCA 1 x 0.1 mm, PLATE 2 x 0.2 mm -> top at y = 0.6 mm
ROW_H = [0.05 * MM, 0.05 * MM, 0.1 * MM, 0.2 * MM, 0.2 * MM]
ROW_PART = [1, 1, 2, 3, 3]
PART_NAMES = ["ball", "CG", "OCA", "PLATE"]
DX = 0.1 * MM


def _scene_mesh(x_panel, x_ball, *, ball_rows=3):
    """Layered panel on columns ``x_panel`` and a ball block on columns ``x_ball`` 10 um above it
    (3 rows of 0.1 mm). Returns a Trajectory (zero fields, 2 frames) and index helpers
    panel_cell(row_from_top, col), ball_cell(row_from_bottom, col)."""
    top = sum(ROW_H)
    ys = top - np.concatenate([[0.0], np.cumsum(ROW_H)])[::-1]            # bottom -> top
    p_pts, p_cells = tensor_grid(x_panel, ys, 0)
    b_pts, b_cells = tensor_grid(x_ball, top + 0.01 * MM + DX * np.arange(ball_rows + 1), len(p_pts))
    n_rows = len(ROW_H)
    p_part = np.repeat(np.array(ROW_PART[::-1]), len(x_panel) - 1)        # rows stored bottom -> top
    points = np.concatenate([p_pts, b_pts])
    cells = np.concatenate([p_cells, b_cells])
    cell_part = np.concatenate([p_part, np.zeros(len(b_cells), int)]).astype(np.int32)
    stiffness = np.array([200e9, 77e9, 1e6, 69e9])
    node_part = geometry.stiffest_adjacent_part(cells, cell_part, stiffness, n_nodes=len(points))
    node_type = node_part.copy()
    node_type[points[:, 1] == 0.0] = len(PART_NAMES)                      # clamped plate bottom
    rng = np.random.default_rng(1)
    n, t = len(points), 2
    traj = Trajectory(points=points, cells=cells, cell_part=cell_part, node_part=node_part,
                      node_type=node_type, times=np.array([0.0, 4e-6]),
                      displacement=rng.standard_normal((t, n, 2)) * 1e-6,
                      velocity=rng.standard_normal((t, n, 2)), von_mises=rng.random((t, n)) * 1e6,
                      meta={"analysis": "axisymmetric", "part_names": PART_NAMES,
                            "node_ids": (np.arange(n) + 101).tolist()})
    npx, nbx = len(x_panel) - 1, len(x_ball) - 1

    def panel_cell(row_from_top, col):
        return (n_rows - 1 - row_from_top) * npx + col

    def ball_cell(row_from_bottom, col):
        return len(p_cells) + row_from_bottom * nbx + col

    return traj, panel_cell, ball_cell


def _expect(panel_cell, ball_cell, panel_rows, panel_cols, ball_rows, ball_cols):
    return sorted([panel_cell(r, c) for r in panel_rows for c in panel_cols]
                  + [ball_cell(r, c) for r in ball_rows for c in ball_cols])


def _kept_full_cells(full: Trajectory, crop: Trajectory, node_map) -> list[int]:
    rows = {tuple(r): i for i, r in enumerate(full.cells.tolist())}
    return sorted(rows[tuple(r)] for r in node_map[crop.cells].tolist())


# ---- hand-built meshes: kept cells known by construction -----------------------------------------------
def test_axisymmetric_radius_depth_ball_height():
    traj, pc, bc = _scene_mesh(DX * np.arange(11), DX * np.arange(5))      # panel 1 mm, ball 0.4 mm wide
    # radius 0.25 mm: columns 0, 1; depth 0.1 mm: the two CG rows (the limit lies on a node row, inclusive);
    # ball height 0.2 mm: ball rows 0, 1
    crop, node_map = crop_trajectory(traj, radius=0.25 * MM, depth=0.1 * MM, ball_height=0.2 * MM)
    assert _kept_full_cells(traj, crop, node_map) == _expect(pc, bc, [0, 1], [0, 1], [0, 1], [0, 1])
    crop.validate("cropped")
    assert set(crop.cell_part.tolist()) == {0, 1}
    roi = crop.meta[ROI_META_KEY]
    assert roi["radius_m"] == 0.25 * MM and roi["depth_m"] == 0.1 * MM and roi["ball_height_m"] == 0.2 * MM
    assert roi["n_nodes_full"] == traj.n_nodes and roi["node_map"] == node_map.tolist()
    assert roi["x_contact_m"] == 0.0 and math.isclose(roi["y_panel_top_m"], 0.6 * MM)
    assert crop.meta["node_ids"] == (node_map + 101).tolist()
    assert "roi" not in traj.meta                                           # the input is not changed
    # the full thickness and the whole ball
    crop, node_map = crop_trajectory(traj, radius=0.25 * MM)
    assert _kept_full_cells(traj, crop, node_map) == _expect(pc, bc, range(5), [0, 1], range(3), [0, 1])
    assert crop.meta[ROI_META_KEY]["depth_m"] is None
    # fixed nodes stay fixed, the cut edge's nodes keep their type
    np.testing.assert_array_equal(crop.node_type, traj.node_type[node_map])
    assert (crop.node_type == len(PART_NAMES)).sum() == 3                  # x = 0, 0.1, 0.2 mm on y = 0
    np.testing.assert_array_equal(crop.node_part, traj.node_part[node_map])


def test_plane_strain_contact_point_from_the_ball():
    xc = 0.3 * MM
    x_panel = DX * np.arange(-10, 11)                                       # -1 .. 1 mm: 20 columns
    x_ball = xc + DX * np.arange(-2, 3)                                     # 0.1 .. 0.5 mm: 4 columns
    traj, pc, bc = _scene_mesh(x_panel, x_ball)
    traj.meta["analysis"] = "plane_strain"
    # |x - 0.3 mm| <= 0.15 mm: panel columns [0.2, 0.3], [0.3, 0.4] (12, 13); ball columns 1, 2
    crop, node_map = crop_trajectory(traj, radius=0.15 * MM, depth=0.2 * MM, ball_height=0.1 * MM)
    assert math.isclose(crop.meta[ROI_META_KEY]["x_contact_m"], xc)
    assert _kept_full_cells(traj, crop, node_map) == _expect(pc, bc, [0, 1, 2], [12, 13], [0], [1, 2])
    # the contact point given (e.g. by the scene) instead of the ball's lowest nodes
    crop2, node_map2 = crop_trajectory(traj, radius=0.15 * MM, depth=0.2 * MM, ball_height=0.1 * MM,
                                       x_contact=0.4 * MM)
    assert _kept_full_cells(traj, crop2, node_map2) == _expect(pc, bc, [0, 1, 2], [13, 14], [0], [2, 3])
    # a contact point away from the ball leaves no ball cell: the radius is at fault, not ball_height
    with pytest.raises(geometry.RoiCropError, match="keeps no ball cell; widen radius") as err:
        geometry.roi_crop(traj.points, traj.cells, traj.cell_part, radius=0.15 * MM, analysis="plane_strain",
                          x_contact=-0.3 * MM, ball_part=0)
    assert err.value.param == "radius"


def test_fields_put_back_and_twice_cropped_map_composes():
    traj, _, _ = _scene_mesh(DX * np.arange(11), DX * np.arange(5))
    crop, node_map = crop_trajectory(traj, radius=0.45 * MM, depth=0.2 * MM)
    n = traj.n_nodes
    vm = geometry.put_back(crop.von_mises, node_map, n_nodes=n, axis=1)
    disp = geometry.put_back(crop.displacement, node_map, n_nodes=n, axis=1)
    assert vm.shape == traj.von_mises.shape and disp.shape == traj.displacement.shape
    np.testing.assert_array_equal(vm[:, node_map], traj.von_mises[:, node_map])
    np.testing.assert_array_equal(disp[:, node_map], traj.displacement[:, node_map])
    outside = np.setdiff1d(np.arange(n), node_map)
    assert outside.size and np.isnan(vm[:, outside]).all() and np.isnan(disp[:, outside]).all()
    types = geometry.put_back(crop.node_type, node_map, n_nodes=n, fill=-1)
    assert types.dtype == crop.node_type.dtype and (types[outside] == -1).all()
    assert geometry.put_back(crop.node_type, node_map, n_nodes=n).dtype == np.float64   # NaN fill
    with pytest.raises(ValueError, match="node_map has"):
        geometry.put_back(crop.von_mises, node_map, n_nodes=n)               # axis 0 is time
    # crop the crop: meta maps straight to the first full mesh
    crop2, map2 = crop_trajectory(crop, radius=0.25 * MM)
    roi2 = crop2.meta[ROI_META_KEY]
    assert roi2["n_nodes_full"] == n and roi2["previous"]["radius_m"] == 0.45 * MM
    full_map = np.asarray(roi2["node_map"])
    np.testing.assert_array_equal(full_map, node_map[map2])
    np.testing.assert_array_equal(geometry.put_back(crop2.points, full_map, n_nodes=n)[full_map],
                                  traj.points[full_map])


def test_empty_crops_name_the_limit():
    traj, _, _ = _scene_mesh(DX * np.arange(11), DX * np.arange(5))
    p, c, cp = traj.points, traj.cells, traj.cell_part
    for kwargs, param, text in [
            (dict(radius=0.05 * MM), "radius", "no cell lies within the radius"),
            (dict(radius=0.5 * MM, depth=0.01 * MM), "depth", "keeps no panel cell; widen depth"),
            (dict(radius=0.5 * MM, ball_height=0.05 * MM), "ball_height", "keeps no ball cell; widen ball_height"),
            (dict(radius=-1.0), "radius", r"radius must be > 0 \[m\], got -1.0"),
            (dict(radius=1.0, depth=float("nan")), "depth", "depth must be > 0")]:
        with pytest.raises(ValueError, match=text) as err:
            geometry.roi_crop(p, c, cp, **kwargs)
        assert err.value.param == param
        assert "mesh x in [0, 0.001] m" in str(err.value) or "must be > 0" in str(err.value)
    with pytest.raises(ValueError, match="plane strain without ball cells needs x_contact"):
        geometry.roi_crop(p, c, cp, radius=1.0, analysis="plane_strain", ball_part=None)
    with pytest.raises(ValueError, match="axisymmetric contact is on the axis"):
        geometry.roi_crop(p, c, cp, radius=1.0, x_contact=1e-3)


# ---- the generator's ROI: a thin wrapper, same node sets as before the shared rule --------------------
# sha256 (first 16 hex digits) of node_map and of the ROI cells (int64) from crop_roi as it was before the
# rule moved to geometry.roi_crop (commit 05b0f42), with the full / ROI node and cell counts
OLD_ROI = {"tiny": (782, 237, 194, "1d2c174e678b18de", "83f22c074fa2929e"),
           "cpu": (3499, 1144, 1041, "c130ae812e974c13", "a4c9aad4fbabaa37")}


def _sha(a) -> str:
    return hashlib.sha256(np.ascontiguousarray(a, np.int64).tobytes()).hexdigest()[:16]


@pytest.mark.parametrize("preset", sorted(OLD_ROI))
def test_generator_roi_unchanged(preset):
    full = M.build_mesh(default_scene(), preset)
    sub, node_map = M.roi(full, preset)
    assert (full.n_nodes, sub.n_nodes, len(sub.cells), _sha(node_map), _sha(sub.cells)) == OLD_ROI[preset]
    # the same crop through the trajectory path gives the same nodes and cells
    traj = Trajectory(points=full.points, cells=full.cells, cell_part=full.cell_part, node_part=full.node_part,
                      node_type=full.node_type, times=np.zeros(1), displacement=np.zeros((1, full.n_nodes, 2)),
                      velocity=np.zeros((1, full.n_nodes, 2)), von_mises=np.zeros((1, full.n_nodes)),
                      meta={"analysis": "axisymmetric", "part_names": list(full.part_names),
                            "scene": default_scene().to_dict()})
    spec = M.mesh_spec(preset)
    crop, tmap = crop_trajectory(traj, radius=spec.roi_x, ball_height=spec.roi_ball_height)
    np.testing.assert_array_equal(tmap, node_map)
    np.testing.assert_array_equal(crop.cells, sub.cells)


def test_generator_crop_with_depth():
    full = M.build_mesh(default_scene(), "tiny")
    sub, node_map = M.crop_roi(full, roi_x=0.5e-3, roi_ball_height=0.3e-3, depth=0.2e-3)
    panel = sub.cell_part > 0
    top = default_scene().panel_thickness
    assert sub.points[np.unique(sub.cells[panel]), 1].min() >= top - 0.2e-3 * (1 + 1e-9)
    assert len(sub.panel_top) >= 2 and len(sub.ball_surface) >= 2
    assert (sub.node_type == len(full.part_names)).sum() == 0               # the clamped bottom is cut off


# ---- imported meshes ---------------------------------------------------------------------------------
REAL_CDB = FIXTURES / "real" / "ansys" / "plane182_183.cdb"


def test_real_ansys_archive_can_be_cropped():
    """MAPDL 17.2 CDWRITE archive (axisymmetric, mm; x in [20, 90] mm, y in [20, 70] mm), one part, no ball."""
    mesh = imp.read_mesh(REAL_CDB, length_unit="mm", part_names=["plate"], parts={"plate": 1})
    n, t = len(mesh.points), 2
    rng = np.random.default_rng(0)
    traj = imp.build_trajectory(mesh, None, "bottom", np.array([0.0, 1e-6]), rng.standard_normal((t, n, 2)),
                                rng.standard_normal((t, n, 2)), rng.random((t, n)), "ansys-text", {}, None)
    crop, node_map = crop_trajectory(traj, radius=50 * MM, depth=20 * MM)
    crop.validate("cropped archive")
    assert 0 < len(crop.cells) < len(traj.cells)
    x, y = traj.points[:, 0], traj.points[:, 1]
    inside = (x <= 50 * MM * (1 + 1e-9)) & (y >= 50 * MM * (1 - 1e-9))
    kept = np.zeros(len(traj.cells), bool)
    kept[_kept_full_cells(traj, crop, node_map)] = True
    np.testing.assert_array_equal(kept, inside[traj.cells].all(axis=1))     # exactly the cells inside
    assert crop.meta["node_ids"] == np.asarray(traj.meta["node_ids"])[node_map].tolist()
    assert crop.meta[ROI_META_KEY]["y_ball_bottom_m"] is None
    back = geometry.put_back(crop.von_mises, node_map, n_nodes=n, axis=1)
    np.testing.assert_array_equal(back[:, node_map], traj.von_mises[:, node_map])


SCENE = Scene(layers=(Layer("CG", 77e9, 0.21, 0.5e-3, 2500.0), Layer("PLATE", 68.9e9, 0.33, 0.5e-3, 2700.0)),
              design_layers=(), contact_pairs=(("ball", "CG"),))


def _cli_case(tmp_path):
    truth = synthetic_trajectory(n_frames=3)         # ball block 2x1 over CG / PLATE rows, 3 columns of 1 mm
    ids = write_cdb(tmp_path / "model.cdb", truth, unit="mm")
    write_results(tmp_path / "res", truth, ids, unit_len="mm", unit_vel="mm/s", unit_stress="MPa")
    (tmp_path / "scene.json").write_text(json.dumps(SCENE.to_dict()))
    return truth, ["--mesh", str(tmp_path / "model.cdb"), "--results", str(tmp_path / "res"),
                   "--scene", str(tmp_path / "scene.json"), "--parts", "ball=1,CG=2,PLATE=3",
                   "--length_unit", "mm"]


def test_import_cli_crops_before_writing(tmp_path, capsys):
    from experiments.import_ansys import main

    truth, argv = _cli_case(tmp_path)
    assert main(argv + ["--out", str(tmp_path / "o" / "t"), "--roi_radius", "1e-3", "--roi_depth=0.5e-3"]) == 0
    assert "kept 8 of" in capsys.readouterr().err
    traj = read_trajectory(tmp_path / "o" / "t")
    assert len(traj.cells) == 2 and sorted(traj.cell_part.tolist()) == [0, 1]   # one ball, one CG cell
    roi = traj.meta[ROI_META_KEY]
    assert roi["radius_m"] == 1e-3 and roi["depth_m"] == 0.5e-3 and roi["ball_height_m"] is None
    assert roi["n_nodes_full"] == truth.n_nodes
    np.testing.assert_allclose(traj.von_mises, truth.von_mises[:, roi["node_map"]], rtol=1e-12)


@pytest.mark.parametrize("flags, named", [
    (["--roi_radius", "1e-5"], "--roi_radius: 1e-05"),
    (["--roi_radius", "1e-3", "--roi_ball_height", "1e-5"], "--roi_ball_height: 1e-05"),
    (["--roi_depth", "-1"], "--roi_depth: -1.0")])
def test_import_cli_empty_crop_names_the_flag(tmp_path, capsys, flags, named):
    from experiments.import_ansys import main

    _, argv = _cli_case(tmp_path)
    assert main(argv + ["--out", str(tmp_path / "o" / "t")] + flags) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {named}: roi_crop"), err
    assert not (tmp_path / "o").exists() or list((tmp_path / "o").iterdir()) == []
