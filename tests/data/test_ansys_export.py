"""ANSYS-format export of whole datasets and the dataset import back (issue 11's end-to-end data path).

experiments.export_ansys writes DIR/<split>/NAME as EXPORTS/<split>/NAME/{model.cdb, results/, scene.json,
run.json}; experiments.import_ansys --exports reads every run folder back into OUT/<split>/NAME. The round
trip keeps the node order (ANSYS node i + 1 = node i) and every field to text precision, for meshes that
differ between trajectories; bad run folders give one line naming the file and write nothing.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fixtures.ansys_files import write_cdb, write_results
from fixtures.helpers import drop_last_column, make_synthetic_trajectory
from fixtures.synthetic import assert_same
from pcmgn_jax.data import importers as imp
from pcmgn_jax.data.exporters import ExportError, export_trajectory
from pcmgn_jax.data.trajectory_io import read_trajectory, write_trajectory
from pcmgn_jax.scene import Scene

FIELDS_TOL = dict(exact=False, rtol=1e-12, atol=1e-18)   # points: 14 significant digits in the NBLOCK


def _dataset(root: Path) -> dict[str, Path]:
    """Three trajectories on three different meshes (CG thickness, one column fewer) in train/ and test/."""
    trajs = {"train/train_0000": make_synthetic_trajectory(0.8, n_frames=4),
             "train/train_0001": drop_last_column(make_synthetic_trajectory(1.0, n_frames=4)),
             "test/test_0000": make_synthetic_trajectory(1.2, n_frames=4)}
    trajs["train/train_0000"].meta["scene_params"] = {"CG": 80e-6}   # carried through run.json "meta"
    for stem, t in trajs.items():
        write_trajectory(t, root / stem)
    return {stem: root / stem for stem in trajs}


def _check_round_trip(stems, out: Path):
    for stem, path in stems.items():
        ref = read_trajectory(path)
        got = read_trajectory(out / stem)
        assert_same(ref, got, **FIELDS_TOL)                     # same node order, cells, parts, fields
        np.testing.assert_array_equal(got.meta["node_ids"], np.arange(1, ref.n_nodes + 1))
        assert got.meta["scene"] == ref.meta["scene"] and got.meta["design"] == ref.meta["design"]
        assert got.meta["source"] == "ansys-text"


def test_dataset_export_import_round_trip(tmp_path, capsys):
    from experiments.export_ansys import main as export_main
    from experiments.import_ansys import main as import_main

    stems = _dataset(tmp_path / "data")
    exports, out = tmp_path / "exports", tmp_path / "back"
    assert export_main(["--data", str(tmp_path / "data"), "--out", str(exports), "--no_progress"]) == 0
    run = json.loads((exports / "train" / "train_0000" / "run.json").read_text())
    assert run["import"]["parts"] == "ball=1,CG=2,PLATE=3" and run["import"]["length_unit"] == "mm"
    assert run["meta"]["scene_params"] == {"CG": 80e-6}
    assert "--exports" in (exports / "README.md").read_text()
    cdb = (exports / "train" / "train_0000" / "model.cdb").read_text()
    assert "/UNITS" not in cdb and "KEYOP,       1, 3,        1" in cdb and "CMBLOCK,FIXED" in cdb
    head = (exports / "test" / "test_0000" / "results" / "stress_002.txt").read_text().splitlines()[0]
    assert head.endswith("Equivalent (von-Mises) Stress (MPa)")
    # a --scene flag is only the default: each run's own scene.json wins (the meshes' CG thicknesses differ)
    other = tmp_path / "other.json"
    other.write_text(json.dumps(make_synthetic_trajectory(2.0).meta["scene"]))
    assert import_main(["--exports", str(exports), "--out", str(out), "--scene", str(other),
                        "--no_progress"]) == 0
    assert "imported 3, kept 0 up to date, 0 failed" in capsys.readouterr().out
    _check_round_trip(stems, out)
    assert read_trajectory(out / "train/train_0000").meta["scene_params"] == {"CG": 80e-6}

    # rerunning keeps everything; a changed input file re-imports that run only
    assert export_main(["--data", str(tmp_path / "data"), "--out", str(exports), "--no_progress"]) == 0
    assert "exported 0 run(s), kept 3" in capsys.readouterr().out
    assert import_main(["--exports", str(exports), "--out", str(out), "--no_progress"]) == 0
    assert "imported 0, kept 3 up to date" in capsys.readouterr().out
    times = exports / "test" / "test_0000" / "results" / "times.txt"
    times.write_text(times.read_text() + "\n")                 # same times, different bytes
    assert import_main(["--exports", str(exports), "--out", str(out), "--no_progress"]) == 0
    assert "imported 1, kept 2 up to date" in capsys.readouterr().out
    assert not [p for p in out.rglob(".*")]                    # no temporary files left


def test_other_units_and_units_line(tmp_path):
    stems = _dataset(tmp_path / "data")
    ref = read_trajectory(stems["train/train_0001"])
    run = tmp_path / "run"
    export_trajectory(ref, run, length_unit="m", velocity_unit="m/s", stress_unit="Pa", units_line=True)
    assert "/UNITS,SI" in (run / "model.cdb").read_text()
    mesh = imp.read_cdb(run / "model.cdb", scene=Scene.load(run / "scene.json"))   # unit from /UNITS
    traj = imp.import_ansys_text(mesh, run / "results", scene=Scene.load(run / "scene.json"), fixed="FIXED")
    assert_same(ref, traj, **FIELDS_TOL)
    with pytest.raises(ExportError, match=r"run2/model\.cdb: no MAPDL /UNITS system has length unit 'nm'"):
        export_trajectory(ref, tmp_path / "run2", length_unit="nm", velocity_unit="m/s", units_line=True)
    assert not (tmp_path / "run2").exists() and not list(tmp_path.glob(".run2*"))


def test_export_error_names_the_path_and_writes_nothing(tmp_path):
    ref = make_synthetic_trajectory(1.0, n_frames=3)
    (tmp_path / "blocked").write_text("a file where the run folder's parent should be")
    with pytest.raises(ExportError, match=r"blocked.*cannot write"):
        export_trajectory(ref, tmp_path / "blocked" / "run")
    with pytest.raises(ExportError, match=r"unknown stress unit 'kN'"):
        export_trajectory(ref, tmp_path / "run", stress_unit="kN")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocked"]


def test_user_run_folders_with_flags(tmp_path, capsys):
    """A user's own layout: model.cdb + results/ per run, no run.json / scene.json: the flags say it all."""
    from experiments.import_ansys import main

    truths = {"r01": make_synthetic_trajectory(1.0, n_frames=3), "r02": make_synthetic_trajectory(1.1, n_frames=3)}
    for name, t in truths.items():
        ids = write_cdb(tmp_path / "exp" / "train" / name / "model.cdb", t, unit="mm")
        write_results(tmp_path / "exp" / "train" / name / "results", t, ids)
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(truths["r01"].meta["scene"]))
    argv = ["--exports", str(tmp_path / "exp"), "--out", str(tmp_path / "d"), "--scene", str(scene),
            "--parts", "ball=1,CG=2,PLATE=3", "--length_unit", "mm", "--no_progress"]
    assert main(argv) == 0, capsys.readouterr().err
    for name, t in truths.items():
        got = read_trajectory(tmp_path / "d" / "train" / name)
        np.testing.assert_allclose(got.displacement, t.displacement, rtol=1e-12, atol=1e-18)
        np.testing.assert_array_equal(got.node_type, t.node_type)       # --fixed default: bottom
    capsys.readouterr()
    assert main(argv) == 0
    assert "imported 0, kept 2 up to date" in capsys.readouterr().out
    argv[argv.index("--fixed") + 1 if "--fixed" in argv else len(argv):] = []
    assert main(argv + ["--fixed", "none", "--no_progress"]) == 0      # the settings are in the fingerprint
    assert "imported 2, kept 0 up to date" in capsys.readouterr().out
    assert (read_trajectory(tmp_path / "d" / "train" / "r01").node_type < 3).all()


def _replace_row(path: Path, row: int, value: str) -> None:
    lines = path.read_text().splitlines()
    lines[row] = lines[row].rsplit("\t", 1)[0] + "\t" + value
    path.write_text("\n".join(lines) + "\n")


BAD_RUNS = {
    "missing": (lambda r: (r / "results" / "stress_001.txt").unlink(),
                r"results/stress_001\.txt: file missing \(frame 1, result stress\)"),
    "corrupt": (lambda r: _replace_row(r / "results" / "velocity_y_002.txt", 3, "abc"),
                r"results/velocity_y_002\.txt:4: node 3: "
                r"column 'Directional Velocity \(mm/s\)': 'abc' is not a number"),
    "truncated": (lambda r: (r / "results" / "deformation_x_000.txt").write_text(
        "\n".join((r / "results" / "deformation_x_000.txt").read_text().splitlines()[:3]) + "\n"),
                  r"results/deformation_x_000\.txt: node \d+ of the mesh .* has no value"),
    "no_mesh": (lambda r: (r / "model.cdb").unlink(),
                r"train_0001/model\.cdb: mesh file not found \(named by .*train_0001/run\.json \"mesh\"\)"),
}


@pytest.mark.parametrize("case", sorted(BAD_RUNS))
def test_bad_run_one_line_error_nothing_written(tmp_path, capsys, case):
    from experiments.export_ansys import main as export_main
    from experiments.import_ansys import main as import_main

    _dataset(tmp_path / "data")
    exports, out = tmp_path / "exports", tmp_path / "back"
    assert export_main(["--data", str(tmp_path / "data"), "--out", str(exports), "--no_progress"]) == 0
    mutate, pattern = BAD_RUNS[case]
    mutate(exports / "train" / "train_0001")
    capsys.readouterr()
    assert import_main(["--exports", str(exports), "--out", str(out), "--no_progress"]) == 2
    cap = capsys.readouterr()
    errors = [ln for ln in cap.err.splitlines() if ln.startswith("error: ")]
    assert len(errors) == 2, cap.err                 # the run's line and the summary naming the folder
    assert __import__("re").search(pattern, errors[0]), errors[0]
    assert str(exports / "train" / "train_0001") in errors[0] and "train_0001" in errors[1]
    assert "imported 2, kept 0 up to date, 1 failed" in cap.out
    assert sorted(p.name for p in (out / "train").iterdir()) == [f"train_0000.{s}" for s in ("h5", "json", "xdmf")]
    assert not [p for p in out.rglob(".*")]


@pytest.mark.slow
def test_family_tiny_round_trip(tmp_path):
    """Solver trajectories of the scene family (every scene its own mesh) through export and import."""
    from pcmgn_jax.data.dataset import ensure_dataset
    from pcmgn_jax.data.exporters import export_dataset

    data = ensure_dataset(tmp_path / "fam", preset="family_tiny", n_train=2, n_test=1, progress=False)
    export_dataset(data, tmp_path / "exports", progress=False)
    report = imp.import_ansys_dataset(tmp_path / "exports", tmp_path / "back", progress=False)
    assert not report.failed and len(report.imported) == 3
    stems = {f"{s}/{p.stem}": p.with_suffix("") for s in ("train", "test") for p in (data / s).glob("*.json")}
    assert len({read_trajectory(p).n_nodes for p in stems.values()}) == 3     # the meshes differ
    _check_round_trip(stems, tmp_path / "back")
    for stem, path in stems.items():
        back = read_trajectory(tmp_path / "back" / stem)
        assert back.meta["scene_params"] == read_trajectory(path).meta["scene_params"]
