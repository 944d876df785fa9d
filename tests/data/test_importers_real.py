"""Importers against files this project did not write (tests/fixtures/real, see its README), plus the MAPDL
input-file forms the real files do not cover (NBLOCK formats, Workbench ds.dat, non-SOLID EBLOCK).

mapdl-archive (extra ``real``) and lasso-python (extra ``dyna``) are cross-checks only; their tests are
skipped when they are not installed.
"""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from fixtures.helpers import FIXTURES, ROOT
from pcmgn_jax.data import importers as imp
from pcmgn_jax.scene import Layer, Scene

REAL = FIXTURES / "real"
PLANE = REAL / "ansys" / "plane182_183.cdb"
ETBLOCK = REAL / "ansys" / "etblock.cdb"
CORRUPT = REAL / "ansys" / "corrupt_a.cdb"
D3_TEMP = REAL / "lsdyna" / "d3plot_node_temperature" / "d3plot"
D3_BEAM = REAL / "lsdyna" / "d3plot_beamip" / "d3plot"
ALL = {"part_names": ["all"], "parts": {"all": 1}}      # plane182_183: one material, number 1


def _plane_mm():
    return imp.read_mesh(PLANE, length_unit="mm", **ALL)


# ---- plane182_183.cdb: MAPDL 17.2 CDWRITE, axisymmetric, mm, PLANE182 + PLANE183 --------------------------
def test_plane182_183_needs_a_length_unit_and_names_the_flag():
    with pytest.raises(imp.InputFileError, match=r"plane182_183\.cdb: no /UNITS line.*--length_unit mm"):
        imp.read_mesh(PLANE, **ALL)


def test_plane182_183_imports_in_mm_as_axisymmetric_corner_quads():
    mesh = _plane_mm()
    assert len(mesh.cells) == 3000 and len(mesh.points) == 3162          # 8-node quads -> corners
    assert mesh.analysis == "axisymmetric"                                # KEYOPT(3) = 1 on both types
    np.testing.assert_allclose(mesh.points.min(0), [0.020, 0.020])        # KPT 1 at (20, 20) mm
    np.testing.assert_allclose(mesh.points.max(0), [0.090, 0.070])        # KPT 7 at (90, 70) mm
    assert len(mesh.dropped_node_ids) == 6242 - 3162
    assert any("1500 8-node quad(s) reduced to their corner nodes" in n for n in mesh.notes)
    xy = mesh.points[mesh.cells]                                          # every quad has positive area
    area = 0.5 * np.sum(xy[..., 0] * np.roll(xy[..., 1], -1, 1) - np.roll(xy[..., 0], -1, 1) * xy[..., 1], 1)
    assert np.all(np.abs(area) > 0)


def test_plane182_183_matches_mapdl_archive():
    mapdl_archive = pytest.importorskip("mapdl_archive")
    a = mapdl_archive.Archive(str(PLANE), parse_vtk=False)
    assert (a.n_node, a.n_elem) == (6242, 3000)
    mesh = _plane_mm()
    assert len(mesh.cells) == a.n_elem
    # mapdl-archive rows: mat, type, real, secnum, esys, death, solid model, shape, element number, exclude,
    # nodes (I J K L first, then the midside nodes of PLANE183)
    elem = {int(r[8]): [int(v) for v in r[10:14]] for r in a.elem}
    ours = {int(e): mesh.node_ids[c].tolist() for e, c in zip(mesh.cell_ids, mesh.cells)}
    assert ours == elem
    corners = np.unique(np.concatenate(list(elem.values())))
    np.testing.assert_array_equal(np.sort(mesh.node_ids), corners)
    order = np.argsort(np.asarray(a.nnum))
    ref = np.asarray(a.nodes)[order[np.searchsorted(np.asarray(a.nnum)[order], mesh.node_ids)]]
    assert np.all(ref[:, 2] == 0)                                         # mapdl-archive drops z silently
    np.testing.assert_allclose(mesh.points, ref[:, :2] * 1e-3, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(np.sort(mesh.dropped_node_ids),
                                  np.setdiff1d(np.asarray(a.nnum), corners))


def test_plane182_183_keyopt3_checked_against_the_scene():
    scene = Scene(layers=(Layer("CG", 77e9, 0.21, 0.5e-3, 2500.0),), design_layers=(),
                  contact_pairs=(("ball", "CG"),), analysis="plane_strain")
    with pytest.raises(imp.InputFileError, match=r"plane182_183\.cdb:168: element type 1 is axisymmetric "
                                                 r"\(KEYOPT\(3\)=1\) but the scene's analysis is 'plane_strain'"):
        imp.read_mesh(PLANE, scene=scene, parts={"ball": 1}, length_unit="mm")
    mesh = imp.read_mesh(PLANE, scene=dataclasses.replace(scene, analysis="axisymmetric"), parts={"ball": 1},
                         length_unit="mm")
    assert len(mesh.cells) == 3000


def _write_tables(folder: Path, node_ids, xy_mm, n_frames=2):
    """Mechanical-style exports for every archive node (midside nodes included), values a function of x, y."""
    folder.mkdir()
    for k in range(n_frames):
        for key, col in (("deformation_x", "Directional Deformation (mm)"),
                         ("deformation_y", "Directional Deformation (mm)"),
                         ("velocity_x", "Directional Velocity (mm/s)"), ("velocity_y", "Directional Velocity (mm/s)"),
                         ("stress", "Equivalent (von-Mises) Stress (MPa)")):
            vals = (k + 1) * (1e-3 * xy_mm[:, 0] + 2e-3 * xy_mm[:, 1])
            rows = ["\t".join(["Node Number", "X Location (mm)", "Y Location (mm)", "Z Location (mm)", col])]
            rows += [f"{n}\t{x!r}\t{y!r}\t0.\t{v!r}" for n, (x, y), v in zip(node_ids.tolist(), xy_mm.tolist(),
                                                                            vals.tolist())]
            (folder / f"{key}_{k:03d}.txt").write_text("\n".join(rows) + "\n")


def test_plane182_183_with_text_exports_through_the_cli(tmp_path, capsys):
    """Result tables list the midside nodes too: they are ignored, and the CLI writes a trajectory."""
    from experiments.import_ansys import main

    text = PLANE.read_text()
    nb = text.splitlines()
    start = next(i for i, ln in enumerate(nb) if ln.startswith("NBLOCK")) + 2
    ids, xy = [], []
    for ln in nb[start:]:
        if ln.startswith("N,"):
            break
        ids.append(int(ln[:9]))
        xy.append([float(ln[27:48]), float(ln[48:69])])
    _write_tables(tmp_path / "res", np.array(ids), np.array(xy))
    out = tmp_path / "out"
    base = ["--mesh", str(PLANE), "--results", str(tmp_path / "res"), "--out", str(out / "t"),
            "--part_names", "all", "--parts", "all=1", "--output_dt", "4e-6"]
    assert main(base) == 2                                                 # no /UNITS, no --length_unit
    assert "--length_unit" in capsys.readouterr().err and not out.exists()
    assert main(base + ["--length_unit", "m"]) == 2                        # wrong unit: caught, with the hint
    err = capsys.readouterr().err
    assert "X/Y Location" in err and "--length_unit" in err and not out.exists()
    assert main(base + ["--length_unit", "mm"]) == 0
    captured = capsys.readouterr()
    assert "3162 nodes, 3000 cells, 2 frames" in captured.out
    assert "note:" in captured.err and "midside" in captured.err
    from pcmgn_jax.data.trajectory_io import read_trajectory

    traj = read_trajectory(out / "t")
    assert traj.meta["analysis"] == "axisymmetric"
    p_mm = traj.points * 1e3
    np.testing.assert_allclose(traj.displacement[1, :, 0], 2 * (1e-3 * p_mm[:, 0] + 2e-3 * p_mm[:, 1]) * 1e-3,
                               rtol=1e-12)


# ---- etblock.cdb (SHELL181 in an ETBLOCK) and corrupt_a.cdb (truncated NBLOCK) -----------------------------
def test_etblock_shells_refused_with_type_line_and_fix():
    with pytest.raises(imp.InputFileError, match=r"etblock\.cdb:5: element type 1 is SHELL181 \(shell\), used by 1 "
                                                 r"element\(s\), e\.g\. 1: only 2D structural solids .* fix: mesh"):
        imp.read_mesh(ETBLOCK, part_names=["a"], parts={"a": 1})


def test_etblock_cross_check_with_mapdl_archive():
    mapdl_archive = pytest.importorskip("mapdl_archive")
    a = mapdl_archive.Archive(str(ETBLOCK), parse_vtk=False)
    assert np.asarray(a.ekey).tolist() == [[1, 181]]                       # what we refuse, it reads as-is


@pytest.mark.parametrize("path, pattern", [
    (CORRUPT, r"corrupt_a\.cdb:143: NUL bytes in a text archive: the file is truncated or corrupt; re-export it"),
    (ETBLOCK, r"etblock\.cdb:5: element type 1 is SHELL181"),
])
def test_bad_real_archives_clear_error_and_nothing_written(tmp_path, capsys, path, pattern):
    from experiments.import_ansys import main

    (tmp_path / "res").mkdir()
    out = tmp_path / "out"
    out.mkdir()
    assert main(["--mesh", str(path), "--results", str(tmp_path / "res"), "--out", str(out / "t"),
                 "--part_names", "a", "--parts", "a=1", "--length_unit", "m", "--output_dt", "1e-6"]) == 2
    err = capsys.readouterr().err.strip()
    assert re.search(pattern, err), err
    assert len(err.splitlines()) == 1                                      # one line
    assert list(out.iterdir()) == []


def test_corrupt_archive_also_refused_by_mapdl_archive():
    mapdl_archive = pytest.importorskip("mapdl_archive")
    with pytest.raises(RuntimeError, match="corrupt"):
        mapdl_archive.Archive(str(CORRUPT), parse_vtk=False)


# ---- NBLOCK formats, Workbench input files, non-SOLID EBLOCK (F3, F4) ------------------------------------
_SQUARE = [(1, 0.0, 0.0), (2, 2.0, 0.0), (3, 2.0, 1.0), (4, 0.0, 1.0), (5, 1.0, 0.0), (6, 1.0, 1.0)]


def test_nblock_every_format_group_and_etblock_keyopt(tmp_path):
    lines = ["/PREP7", "/UNITS,MPA", "ETBLOCK,        1,        1", "(2i9,19a9)",
             "".join(f"{v:9d}" for v in [1, 182, 0, 0, 2] + [0] * 16), "       -1",
             "NBLOCK,6,SOLID,         6,         6", "(1i7,2i9,6e21.13)"]
    lines += [f"{n:7d}{0:9d}{0:9d}{x:21.13E}{y:21.13E}" for n, x, y in _SQUARE]
    lines += ["N,R5.3,LOC,       -1,", "EBLOCK,19,SOLID,         2,         2", "(19i9)"]
    for e, nodes in ((1, [1, 5, 6, 4]), (2, [5, 2, 3, 6])):
        lines.append("".join(f"{v:9d}" for v in [1, 1, 1, 1, 0, 0, 0, 0, 4, 0, e] + nodes))
    lines.append("       -1")
    (tmp_path / "m.cdb").write_text("\n".join(lines) + "\n")
    mesh = imp.read_mesh(tmp_path / "m.cdb", part_names=["a"], parts={"a": 1})      # /UNITS,MPA: mm
    np.testing.assert_allclose(mesh.points, np.array([p[1:] for p in _SQUARE]) * 1e-3)
    assert mesh.analysis == "plane_strain"
    assert imp.fortran_layout("(1i7,2i9,6e21.13)", "x") == [("i", 7)] + [("i", 9)] * 2 + [("f", 21)] * 6


def _ds_dat(body_nblock: str) -> str:
    """A Workbench-style input file: lower-case commands, *set parameters, contact in a non-SOLID EBLOCK."""
    return "\n".join([
        "/batch", "/wb,file,start", "/prep7", "/units,mpa",
        "*set,tid,3", "*set,cid,4",
        "et,1,183", "keyo,1,3,1",
        body_nblock,
        "et,tid,170", "et,cid,174",
        "eblock,19,solid,,1", "(19i9)",
        "".join(f"{v:9d}" for v in [1, 1, 1, 1, 0, 0, 0, 0, 8, 0, 1, 1, 2, 3, 4, 5, 7, 6, 8]),
        "-1",
        "eblock,10,,,1", "(15i9)",
        "".join(f"{v:9d}" for v in [2, 4, 4, 4, 0, 1, 2, 3, 3]),
        "-1",
        "/wb,file,end", ""])


def test_workbench_dat_goes_to_the_cdb_reader_and_skips_non_solid_eblock(tmp_path):
    pts = [(1, 0, 0), (2, 2, 0), (3, 2, 2), (4, 0, 2), (5, 1, 0), (6, 2, 1), (7, 1, 2), (8, 0, 1)]
    nblock = "\n".join(["nblock,3,,8", "(1i9,3e20.9e3)"] + [f"{n:9d}{x:20.9E}{y:20.9E}{0.0:20.9E}" for n, x, y in pts]
                       + ["-1"])
    (tmp_path / "ds.dat").write_text(_ds_dat(nblock))
    assert imp.is_mapdl_file(tmp_path / "ds.dat")
    mesh = imp.read_mesh(tmp_path / "ds.dat", part_names=["a"], parts={"a": 1})
    assert mesh.node_ids.tolist() == [1, 2, 3, 4] and len(mesh.cells) == 1
    np.testing.assert_allclose(mesh.points[mesh.cells[0]], np.array([[0, 0], [2, 0], [2, 2], [0, 2]]) * 1e-3)
    assert mesh.analysis == "axisymmetric"
    assert any("non-SOLID form" in n for n in mesh.notes)
    # a .dat with no NBLOCK still goes to meshio, with a one-line error that names the alternatives
    (tmp_path / "other.dat").write_text("something else\n")
    with pytest.raises(imp.InputFileError, match=r"other\.dat: meshio cannot read it .*NBLOCK"):
        imp.read_mesh(tmp_path / "other.dat", part_names=["a"])


def test_plane_stress_keyopt_refused(tmp_path):
    pts = [(1, 0, 0), (2, 1, 0), (3, 1, 1), (4, 0, 1)]
    base = ["/units,si", "et,1,182", "keyopt,1,3,0", "nblock,3,,4", "(1i9,3e20.9e3)"]
    element = [1, 1, 1, 1, 0, 0, 0, 0, 4, 0, 1, 1, 2, 3, 4]
    base += [f"{n:9d}{x:20.9E}{y:20.9E}" for n, x, y in pts] + ["-1", "eblock,19,solid,,1", "(19i9)",
                                                                 "".join(f"{v:9d}" for v in element), "-1"]
    (tmp_path / "ps.cdb").write_text("\n".join(base) + "\n")
    with pytest.raises(imp.InputFileError, match=r"ps\.cdb:2: element type 1 \(PLANE182\) has KEYOPT\(3\)=0 "
                                                 r"\(plane stress\).*set KEYOPT\(3\)"):
        imp.read_mesh(tmp_path / "ps.cdb", part_names=["a"], parts={"a": 1})


# ---- LS-DYNA d3plots (lasso-python, the `dyna` extra) ------------------------------------------------------
def test_d3plot_part_titles_decoded_and_counts_match_lasso():
    pytest.importorskip("lasso.dyna")
    from lasso.dyna import ArrayType as AT, D3plot

    arr = D3plot(str(D3_TEMP)).arrays
    raw = list(arr[AT.part_titles])
    assert isinstance(raw[0], bytes)                                        # why titles never matched before
    parts = imp.d3plot_parts(D3_TEMP)
    assert [p.title for p in parts] == [t.decode().strip() for t in raw] == ["Profil_Shells"]
    assert [p.part_id for p in parts] == np.asarray(arr[AT.part_titles_ids]).tolist()
    assert parts[0].n_shells == len(arr[AT.element_shell_ids]) == 2075
    assert parts[0].n_nodes == len(arr[AT.node_ids]) == 2185
    # default part mapping by title now finds the part (case-insensitive); the file then fails on its
    # 12 triangles, with a one-line error naming the element, the part and the fix
    with pytest.raises(imp.InputFileError, match=r"d3plot: element \d+ \(part 'profil_shells', LS-DYNA part "
                                                 r"1000000\) is a degenerate quad \(triangle\), 12 such.*remesh"):
        imp.import_d3plot(D3_TEMP, part_names=["profil_shells"])


def test_d3plot_of_beams_refused():
    pytest.importorskip("lasso.dyna")
    assert [(p.title, p.n_shells) for p in imp.d3plot_parts(D3_BEAM)] == [("SECTION_BEAM", 0)]
    with pytest.raises(imp.InputFileError, match=r"d3plot has no shell elements \(it has beams\)"):
        imp.import_d3plot(D3_BEAM, part_names=["SECTION_BEAM"])


def test_real_fixtures_are_the_shared_copies():
    """The README lists every file; the copies are what shared/real_files holds (when it is there)."""
    readme = (REAL / "README.md").read_text()
    for p in (PLANE, ETBLOCK, CORRUPT, D3_TEMP.parent, D3_BEAM.parent):
        assert str(p.relative_to(REAL)) in readme
    shared = ROOT.parent / "shared" / "real_files"
    if not shared.is_dir():
        pytest.skip("shared/real_files not next to the repository")
    for f in sorted(q for q in shared.rglob("*") if q.is_file()):
        assert (REAL / f.relative_to(shared)).read_bytes() == f.read_bytes(), f
