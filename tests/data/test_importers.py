"""Importers: ANSYS text + .cdb, meshio meshes / series, d3plot (optional); bad input writes nothing."""
from __future__ import annotations

import json
from pathlib import Path

import meshio
import numpy as np
import pytest

from fixtures.ansys_files import node_numbers, write_cdb, write_results
from fixtures.synthetic import PART_NAMES, assert_same, synthetic_trajectory
from pcmgn_jax.data import importers as imp
from pcmgn_jax.data.trajectory_io import read_trajectory, write_trajectory
from pcmgn_jax.scene import Layer, Scene

SCENE = Scene(layers=(Layer("CG", 77e9, 0.21, 0.5e-3, 2500.0), Layer("PLATE", 68.9e9, 0.33, 0.5e-3, 2700.0)),
              design_layers=(), contact_pairs=(("ball", "CG"),))
PARTS = {"ball": 1, "CG": 2, "PLATE": 3}        # cdb material numbers
TOL = dict(exact=False, rtol=1e-12, atol=1e-18)


def _truth():
    return synthetic_trajectory(n_frames=3, meta={"source": "solver"})


def _ansys_case(tmp_path, *, unit="mm", unit_vel="mm/s", unit_stress="MPa"):
    truth = _truth()
    ids = write_cdb(tmp_path / "model.cdb", truth, unit=unit)
    write_results(tmp_path / "res", truth, ids, unit_len=unit, unit_vel=unit_vel, unit_stress=unit_stress)
    return truth, ids


@pytest.mark.parametrize("units", [("mm", "mm/s", "MPa"), ("m", "m/s", "Pa")])
def test_ansys_text_reproduces_written_trajectory(tmp_path, units):
    truth, ids = _ansys_case(tmp_path, unit=units[0], unit_vel=units[1], unit_stress=units[2])
    write_trajectory(truth, tmp_path / "solver_path")
    ref = read_trajectory(tmp_path / "solver_path")
    traj = imp.import_ansys_text(tmp_path / "model.cdb", tmp_path / "res", scene=SCENE, parts=PARTS,
                                 length_unit=units[0])
    assert_same(ref, traj, **TOL)
    assert traj.meta["source"] == "ansys-text" and traj.meta["part_names"] == list(PART_NAMES)
    assert traj.meta["node_ids"] == ids.tolist()
    write_trajectory(traj, tmp_path / "imported")            # and it is a valid trajectory file
    assert_same(ref, read_trajectory(tmp_path / "imported"), **TOL)


def test_cdb_components_contact_elements_and_frames_manifest(tmp_path):
    truth = _truth()
    n_cells = len(truth.cells)
    comps = {name.upper(): ("ELEM", [1001 + e for e in range(n_cells) if truth.cell_part[e] == pid])
             for pid, name in enumerate(PART_NAMES)}
    ids = node_numbers(truth.n_nodes)
    comps["BASE"] = ("NODE", ids[truth.node_type == 3].tolist())
    # a CONTA172 (type 2) 3-node element, as Mechanical writes for contact: skipped
    contact = "".join(f"{v:9d}" for v in [9, 2, 9, 9, 0, 0, 0, 0, 3, 0, 5001, ids[8], ids[9], ids[9]])
    write_cdb(tmp_path / "m.cdb", truth, unit="m", mats=np.full(n_cells, 7), components=comps,
              extra_elements=contact)
    res = tmp_path / "res"
    write_results(res, truth, ids, unit_len="m", unit_vel="m/s", unit_stress="Pa", times_file=False)
    for k in range(truth.n_frames):   # custom names listed in frames.json instead of the convention
        for key in imp.FRAME_KEYS:
            (res / f"{key}_{k:03d}.txt").rename(res / f"f{k}_{key}.tab")
    (res / "frames.json").write_text(json.dumps({"time_unit": "us", "frames": [
        {"time": float(t * 1e6), **{key: f"f{k}_{key}.tab" for key in imp.FRAME_KEYS}}
        for k, t in enumerate(truth.times)]}))
    traj = imp.import_ansys_text(tmp_path / "m.cdb", res, scene=SCENE, fixed="BASE",   # parts by name
                                 length_unit="m")
    assert_same(truth, traj, exact=False, rtol=1e-12, atol=1e-18)


def test_meshio_mesh_with_ansys_text(tmp_path):
    truth = _truth()
    sets = {name: [np.nonzero(truth.cell_part == pid)[0]] for pid, name in enumerate(PART_NAMES)}
    meshio.write(tmp_path / "m.inp", meshio.Mesh(truth.points, [("quad", truth.cells)], cell_sets=sets))
    ids = np.arange(1, truth.n_nodes + 1)        # meshio meshes: ANSYS node number = index + 1
    write_results(tmp_path / "res", truth, ids)
    traj = imp.import_ansys_text(tmp_path / "m.inp", tmp_path / "res", part_names=PART_NAMES)
    assert_same(truth, traj, exact=False, rtol=1e-12, atol=1e-18)   # no scene: node part = lowest id
    assert traj.meta["scene"] is None


@pytest.mark.parametrize("kind", ["vtu", "xdmf"])
def test_meshio_series_reproduces_written_trajectory(tmp_path, kind):
    truth = _truth()
    write_trajectory(truth, tmp_path / "solver_path")
    ref = read_trajectory(tmp_path / "solver_path")
    parts = {name: pid for pid, name in enumerate(PART_NAMES)}
    if kind == "vtu":
        files = []
        for k in range(truth.n_frames):
            pad = lambda a: np.concatenate([a, np.zeros((len(a), 1))], axis=1)  # noqa: E731
            m = meshio.Mesh(truth.points * 1e3, [("quad", truth.cells)],     # one unit system: mm
                            point_data={"U": pad(truth.displacement[k]) * 1e3, "V": truth.velocity[k],
                                        "S": truth.von_mises[k] * 1e-6},
                            cell_data={"part": [truth.cell_part]})
            files.append(tmp_path / f"f{k}.vtu")
            meshio.write(files[-1], m)
        traj = imp.import_meshio_series(files, scene=SCENE, parts=parts, part_field="part",
                                        times=truth.times, fields={"displacement": "U", "velocity": "V",
                                                                   "von_mises": "S"},
                                        length_unit="mm", velocity_unit="m/s", stress_unit="MPa")
    else:   # our own XDMF read back as a generic meshio time series
        traj = imp.import_meshio_series(tmp_path / "solver_path.xdmf", scene=SCENE, parts=parts,
                                        part_field="part")
    assert_same(ref, traj, **TOL)
    assert traj.meta["source"] == "meshio"


# ---- bad input: clear message, nothing written -----------------------------------------------------
def _edit(path: Path, fn):
    path.write_text(fn(path.read_text()))


def _set_row(text, row, col, value):
    lines = text.splitlines()
    f = lines[row].split("\t")
    f[col] = value
    lines[row] = "\t".join(f)
    return "\n".join(lines) + "\n"


BAD_CASES = {
    "renamed_column": (lambda d: _edit(d / "res" / "deformation_y_001.txt",
                                       lambda t: t.replace("Directional Deformation", "Total Deformation")),
                       r"deformation_y_001\.txt:1: missing column 'Directional Deformation"),
    "missing_column": (lambda d: _edit(d / "res" / "stress_000.txt",
                                       lambda t: t.replace("Node Number", "Node")),
                       r"stress_000\.txt:1: missing column 'Node Number'"),
    "unknown_unit": (lambda d: _edit(d / "res" / "velocity_x_002.txt",
                                     lambda t: t.replace("(mm/s)", "(furlong/s)")),
                     r"velocity_x_002\.txt:1: column 'Directional Velocity \(furlong/s\)': unknown velocity unit"),
    "unknown_stress_unit": (lambda d: _edit(d / "res" / "stress_001.txt", lambda t: t.replace("(MPa)", "(bar)")),
                            r"stress_001\.txt:1: column 'Equivalent \(von-Mises\) Stress \(bar\)'"),
    "nan": (lambda d: _edit(d / "res" / "stress_002.txt", lambda t: _set_row(t, 4, 4, "NaN")),
            r"stress_002\.txt:5: node \d+: column 'Equivalent \(von-Mises\) Stress \(MPa\)': non-finite"),
    "inf": (lambda d: _edit(d / "res" / "deformation_x_000.txt", lambda t: _set_row(t, 2, 4, "inf")),
            r"deformation_x_000\.txt:3: node \d+: column 'Directional Deformation \(mm\)': non-finite"),
    "node_not_in_mesh": (lambda d: _edit(d / "res" / "velocity_y_001.txt", lambda t: _set_row(t, 3, 0, "99999")),
                         r"velocity_y_001\.txt:4: node 99999 is not in the mesh"),
    "different_node_sets": (lambda d: _edit(d / "res" / "deformation_x_001.txt",
                                            lambda t: "\n".join(t.splitlines()[:-1]) + "\n"),
                            r"deformation_x_001\.txt: node \d+ of deformation_x_000\.txt is missing "
                            r"\(frames/results have different node sets\)"),
    "duplicate_node": (lambda d: _edit(d / "res" / "velocity_x_000.txt",
                                       lambda t: t + t.splitlines()[2] + "\n"),
                       r"velocity_x_000\.txt:20: duplicate node number 104 \(first on line 3\)"),
    "wrong_location": (lambda d: _edit(d / "res" / "stress_000.txt", lambda t: _set_row(t, 2, 1, "0.5")),
                       r"stress_000\.txt:3: node 104: X/Y Location"),
    "missing_frame_file": (lambda d: (d / "res" / "velocity_y_001.txt").unlink(),
                           r"velocity_y_001\.txt: file missing \(frame 1, result velocity_y\)"),
    "non_quad_cell": (lambda d: _edit(d / "model.cdb", lambda t: t.replace(
        "".join(f"{v:9d}" for v in [1, 1, 1, 1, 0, 0, 0, 0, 4, 0, 1001]),
        "".join(f"{v:9d}" for v in [1, 1, 1, 1, 0, 0, 0, 0, 3, 0, 1001]))),
                      r"model\.cdb:\d+: element 1001 \(part 'ball'\) has nodes \[.*\]: not a 4-node quad"),
    "duplicate_mesh_node": (lambda d: _edit(d / "model.cdb", lambda t: t.replace(
        f"{104:9d}{0:9d}", f"{101:9d}{0:9d}", 1)),
                            r"model\.cdb:\d+: duplicate node number 101"),
    "unmapped_material": (lambda d: _edit(d / "model.cdb", lambda t: t.replace(
        "".join(f"{v:9d}" for v in [3, 1, 1, 1, 0, 0, 0, 0, 4, 0, 1003]),
        "".join(f"{v:9d}" for v in [8, 1, 1, 1, 0, 0, 0, 0, 4, 0, 1003]))),
                          r"model\.cdb: 1 element\(s\) belong to no part, e\.g\. element \[1003\]"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input_clear_error_and_nothing_written(tmp_path, case, capsys):
    from experiments.import_ansys import main

    _ansys_case(tmp_path)
    mutate, pattern = BAD_CASES[case]
    mutate(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    argv = ["--mesh", str(tmp_path / "model.cdb"), "--results", str(tmp_path / "res"),
            "--out", str(out / "traj"), "--part_names", ",".join(PART_NAMES),
            "--parts", "ball=1,CG=2,PLATE=3", "--length_unit", "mm"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert __import__("re").search(pattern, err), err
    assert list(out.iterdir()) == []


def test_cli_success(tmp_path, capsys):
    from experiments.import_ansys import main

    truth, _ = _ansys_case(tmp_path)
    (tmp_path / "scene.json").write_text(json.dumps(SCENE.to_dict()))
    assert main(["--mesh", str(tmp_path / "model.cdb"), "--results", str(tmp_path / "res"),
                 "--out", str(tmp_path / "o" / "t"), "--scene", str(tmp_path / "scene.json"),
                 "--parts", "ball=1,CG=2,PLATE=3", "--length_unit", "mm"]) == 0
    assert "3 frames" in capsys.readouterr().out
    assert_same(truth, read_trajectory(tmp_path / "o" / "t"), **TOL)


def test_meshio_bad_inputs(tmp_path):
    truth = _truth()
    tri = np.array([[0, 1, 5]])
    meshio.write(tmp_path / "tri.vtu", meshio.Mesh(truth.points, [("quad", truth.cells), ("triangle", tri)]))
    with pytest.raises(imp.InputFileError, match=r"tri\.vtu: cell block 1 has 1 'triangle' cells"):
        imp.read_meshio_mesh(tmp_path / "tri.vtu", part_names=PART_NAMES)
    meshio.write(tmp_path / "m.vtu", meshio.Mesh(truth.points, [("quad", truth.cells)],
                                                 cell_data={"part": [truth.cell_part]}))
    with pytest.raises(imp.InputFileError, match=r"m\.vtu: part 'ball': no cell set named 'ball'"):
        imp.read_meshio_mesh(tmp_path / "m.vtu", part_names=PART_NAMES)
    pts = truth.points.copy()
    pts[3] += 1e-3
    meshio.write(tmp_path / "f1.vtu", meshio.Mesh(pts, [("quad", truth.cells)], cell_data={"part": [truth.cell_part]}))
    for f in ("m.vtu", "f1.vtu"):
        m = meshio.read(tmp_path / f)
        m.point_data.update(displacement=truth.displacement[0], velocity=truth.velocity[0],
                            von_mises=truth.von_mises[0])
        meshio.write(tmp_path / f, m)
    with pytest.raises(imp.InputFileError, match=r"f1\.vtu: points differ from frame 0"):
        imp.import_meshio_series([tmp_path / "m.vtu", tmp_path / "f1.vtu"], part_names=PART_NAMES,
                                 parts={n: i for i, n in enumerate(PART_NAMES)}, part_field="part",
                                 output_dt=1e-6)


def test_units_and_parts_helpers():
    assert imp.parse_parts("ball=1,CG=2+7,OCA1=OCA_1") == {"ball": [1], "CG": [2, 7], "OCA1": ["OCA_1"]}
    assert imp.length_factor("µm", "x") == 1e-6
    with pytest.raises(imp.InputFileError, match="here: unknown length unit 'yd'"):
        imp.length_factor("yd", "here")
    s = np.array([[100.0, 0, 0, 0, 0, 0]])
    assert imp.von_mises_from_tensor(s)[0] == pytest.approx(100.0)


def test_d3plot_clear_error_without_lasso(tmp_path):
    try:
        import lasso  # noqa: F401
        pytest.skip("lasso-python is installed")
    except ImportError:
        pass
    with pytest.raises(ImportError, match=r'pip install -e "\.\[dyna\]"'):
        imp.import_d3plot(tmp_path / "d3plot", part_names=PART_NAMES)


def test_d3plot_round_trip(tmp_path):
    pytest.importorskip("lasso.dyna")
    from lasso.dyna import ArrayType as AT, D3plot

    truth = _truth()
    d = D3plot()
    pts3 = np.concatenate([truth.points, np.zeros((truth.n_nodes, 1))], axis=1)
    d.arrays[AT.node_coordinates] = pts3
    d.arrays[AT.node_ids] = np.arange(1, truth.n_nodes + 1)
    pos = pts3[None] + np.concatenate([truth.displacement, np.zeros((truth.n_frames, truth.n_nodes, 1))], axis=2)
    d.arrays[AT.node_displacement] = pos
    d.arrays[AT.node_velocity] = np.concatenate([truth.velocity, np.zeros((truth.n_frames, truth.n_nodes, 1))], 2)
    d.arrays[AT.global_timesteps] = truth.times
    d.arrays[AT.element_shell_node_indexes] = truth.cells.astype(np.int32)
    d.arrays[AT.element_shell_part_indexes] = truth.cell_part.astype(np.int32)
    d.arrays[AT.element_shell_ids] = np.arange(1, len(truth.cells) + 1)
    d.arrays[AT.part_ids] = np.arange(1, len(PART_NAMES) + 1)
    # titles as LS-DYNA stores them (80 blank-padded bytes); lasso hands them back as bytes
    d.arrays[AT.part_titles] = np.array([n.upper().encode().ljust(80) for n in PART_NAMES])
    d.arrays[AT.part_titles_ids] = np.arange(1, len(PART_NAMES) + 1)
    d.write_d3plot(str(tmp_path / "d3plot"))
    traj = imp.import_d3plot(tmp_path / "d3plot", scene=SCENE, parts={"ball": 1, "CG": 2, "PLATE": 3})
    np.testing.assert_allclose(traj.displacement, truth.displacement, atol=1e-9)
    assert traj.meta["source"] == "d3plot"
    by_title = imp.import_d3plot(tmp_path / "d3plot", scene=SCENE)     # default: parts by title
    np.testing.assert_array_equal(by_title.cell_part, truth.cell_part)


def test_cli_every_flag_keeps_its_spelling(tmp_path, capsys):
    """The tyro CLI accepts every flag of the former argparse one, with underscores, and --ignore_unmapped bare."""
    from experiments.import_ansys import main

    _ansys_case(tmp_path)
    (tmp_path / "res" / "times.txt").unlink()
    argv = ["--mesh", str(tmp_path / "model.cdb"), "--results", str(tmp_path / "res"), "--out", str(tmp_path / "t"),
            "--part_names", ",".join(PART_NAMES), "--parts", "ball=1,CG=2", "--output_dt", "2e-6",
            "--length_unit", "mm", "--fixed", "none", "--location_tol", "1e-6", "--ignore_unmapped"]
    assert main(argv) == 0, capsys.readouterr().err
    traj = read_trajectory(tmp_path / "t")
    assert set(traj.cell_part.tolist()) == {0, 1}                  # PLATE cells dropped (unmapped)
    assert (traj.node_type < len(PART_NAMES)).all()                # --fixed none
    np.testing.assert_allclose(np.diff(traj.times), 2e-6)


def test_cli_unknown_flag_named(capsys):
    from experiments.import_ansys import main

    assert main(["--mesh", "m.cdb", "--results", "r", "--out", "o", "--length_units", "mm"]) == 2
    assert "--length_units (did you mean --length_unit?)" in capsys.readouterr().err
