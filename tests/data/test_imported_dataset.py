"""Training and evaluation on an imported dataset: a folder of trajectory files without a manifest.

``experiments.train --dataset_dir DIR`` reads ``DIR/train``/``DIR/test`` as they are when there is no
manifest (pcmgn_jax.data.dataset.dataset_source), validates on the last n_val of DIR/train by name, and
never runs the solver there; a folder with neither a manifest nor trajectories is a one-line error that
writes nothing. Slow: family_tiny scenes from the solver -> ANSYS run folders -> dataset import -> train
-> evaluate, all through the command lines.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fixtures.helpers import drop_last_column, make_synthetic_trajectory
from pcmgn_jax import cli
from pcmgn_jax.data import dataset as ds, splits
from pcmgn_jax.data.trajectory_io import write_trajectory


def _tree(root: Path) -> dict[str, int]:
    return {str(p.relative_to(root)): p.stat().st_mtime_ns for p in sorted(root.rglob("*"))}


def _no_solver(monkeypatch):
    def fail(*a, **k):
        raise AssertionError("the solver must not run on an imported dataset")
    monkeypatch.setattr(ds, "ensure_dataset", fail)


@pytest.mark.parametrize("layout", ["empty", "ansys_run_folders"])
def test_train_refuses_a_folder_without_manifest_or_trajectories(tmp_path, capsys, monkeypatch, layout):
    from experiments import train
    data, run = tmp_path / "mine", tmp_path / "run"
    data.mkdir()
    if layout == "ansys_run_folders":    # the exports instead of the imported folder
        (data / "train" / "run01" / "results").mkdir(parents=True)
        (data / "train" / "run01" / "model.cdb").write_text("/PREP7\n")
        (data / "train" / "run01" / "run.json").write_text("{}\n")
    before = _tree(tmp_path)
    _no_solver(monkeypatch)
    rc = cli.run(train.main, ["--preset", "family_tiny", f"--dataset_dir={data}", f"--workdir={run}",
                              "--progress=False"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert err.startswith(f"error: {data}: no manifest.json and no trajectory files in {data / 'train'}")
    assert "experiments.import_ansys --exports" in err and "does not exist yet" in err
    assert _tree(tmp_path) == before and not run.exists()


def _imported(root: Path, n_train: int = 5, n_test: int = 1) -> Path:
    """A folder of trajectory files without a manifest, two meshes, as an importer writes it."""
    for i in range(n_train):
        t = make_synthetic_trajectory(0.8 + 0.1 * i, n_frames=4)
        write_trajectory(drop_last_column(t) if i % 2 else t, root / "train" / f"run{i:02d}")
    for i in range(n_test):
        write_trajectory(make_synthetic_trajectory(1.05 + 0.1 * i, n_frames=4), root / "test" / f"case{i}")
    return root


def test_imported_folder_splits_and_is_never_generated_into(tmp_path):
    root = _imported(tmp_path / "mine")
    assert ds.dataset_source(root) == ds.IMPORTED
    assert ds.dataset_source(tmp_path / "absent") == ds.GENERATE
    names = lambda ts: [t.meta["name"] for t in ts]  # noqa: E731
    train, val, test = splits.load_splits(root, n_train=2, n_val=2, n_test=1)
    assert names(train) == ["run00", "run01"] and names(val) == ["run03", "run04"] and names(test) == ["case0"]
    train, val, _ = splits.load_splits(root, n_train=4, n_val=1, n_test=0)   # the validation run stays run04
    assert names(train) == ["run00", "run01", "run02", "run03"] and names(val) == ["run04"]
    assert names(splits.load_splits(root, n_train=5, n_val=0, n_test=0)[0])[-1] == "run04"
    with pytest.raises(ds.DatasetError, match=r"holds 5 train / 1 test .* \(set --n_train, --n_val and --n_test"):
        splits.load_splits(root, n_train=5, n_val=1, n_test=1)
    before = _tree(root)
    with pytest.raises(ds.DatasetError, match=r"no manifest.json \(an imported dataset\?\); the solver does not"):
        ds.ensure_dataset(root, preset="family_tiny", n_train=2, n_test=1, progress=False)
    assert _tree(root) == before
    assert splits.prepare_dataset(root, preset="family_tiny", n_train=5, n_test=1) == (root, ds.IMPORTED)
    assert _tree(root) == before


def test_pool_two_datasets_renumbers_resumes_and_refuses_mixing(tmp_path, capsys):
    """generate --pool: A's and B's train splits (in order) and A's test split, renumbered, read back as an
    imported dataset with the same arrays; a rerun rewrites nothing; stale files or a manifest refuse."""
    from experiments import generate
    a, b, out = _imported(tmp_path / "a", n_train=3), _imported(tmp_path / "b", n_train=2, n_test=2), tmp_path / "pool"
    assert generate.main(["--out", str(out), "--pool", f"{a},{b}"]) == 0
    train, val, test = splits.load_splits(out, n_train=4, n_val=1, n_test=1)
    src = splits.load_directory(a / "train") + splits.load_directory(b / "train")
    assert [t.meta["name"] for t in train + val] == [f"train_{i:04d}" for i in range(5)]
    for got, want in zip(train + val, src):
        np.testing.assert_array_equal(got.displacement, want.displacement)
        np.testing.assert_array_equal(got.points, want.points)
    assert len(splits.load_directory(out / "test")) == 1    # only the first dataset's test split
    np.testing.assert_array_equal(test[0].von_mises, splits.load_directory(a / "test")[0].von_mises)
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*.h5")}
    assert generate.main(["--out", str(out), "--pool", f"{a},{b}"]) == 0
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*.h5")} == before     # resumed: nothing rewritten
    capsys.readouterr()
    assert generate.main(["--out", str(out), "--pool", f"{a}"]) == 2          # would leave B's scenes behind
    assert "holds trajectories the pool would not write" in capsys.readouterr().err
    assert generate.main(["--out", str(tmp_path / "p2"), "--pool", f"{a},{tmp_path / 'none'}"]) == 2
    assert "no trajectory files to pool (split 'train'" in capsys.readouterr().err


@pytest.mark.slow
def test_family_tiny_export_import_train_evaluate(family_tiny, tmp_path, monkeypatch):
    """Solver scenes (each its own mesh) -> ANSYS run folders -> imported folder -> train -> evaluate."""
    from experiments import evaluate, export_ansys, import_ansys, train
    exports, data, run = tmp_path / "exports", tmp_path / "mine", tmp_path / "run"
    assert export_ansys.main(["--data", str(family_tiny), "--out", str(exports), "--no_progress"]) == 0
    assert import_ansys.main(["--exports", str(exports), "--out", str(data), "--no_progress"]) == 0
    assert not (data / ds.MANIFEST).exists() and ds.dataset_source(data) == ds.IMPORTED
    imported = {s: sorted(p.name for p in (data / s).iterdir()) for s in ("train", "test")}
    assert len(imported["train"]) == 15 and len(imported["test"]) == 6      # 5 + 2 runs x (.xdmf .h5 .json)

    _no_solver(monkeypatch)
    assert train.main(["--preset", "family_tiny", f"--dataset_dir={data}", f"--workdir={run}",
                       "--num_steps=20", "--val_every=20", "--progress=False"]) == 0
    rec = json.loads((run / "data.json").read_text())
    assert rec["source"] == ds.IMPORTED and rec["dataset_dir"] == str(data.resolve())
    assert [t["name"] for t in rec["train"]] == [f"train_{i:04d}" for i in range(4)]
    assert [t["name"] for t in rec["val"]] == ["train_0004"]
    used = rec["train"] + rec["val"]
    assert {t["source"] for t in used} == {"ansys-text"} and len({t["n_nodes"] for t in used}) >= 3
    assert all(len(t["sha256"]) == 64 for t in used)
    # the folder holds what the importer wrote, plus the training cache
    assert {s: sorted(p.name for p in (data / s).iterdir()) for s in ("train", "test")} == imported
    assert sorted(p.name for p in data.iterdir()) == [".cache", "test", "train"]

    assert evaluate.main(["--workdir", str(run)]) == 0
    m = json.loads((run / "eval" / "metrics.json").read_text())
    assert m["n_test"] == 2 and len(set(m["n_nodes_per_trajectory"])) == 2
    for key in ("position_mae_um", "stress_mae_mpa", "oled_objective_area_rel_error_pct_mean", "penetration_max_um"):
        assert np.isfinite(m[key]), key
    assert np.isfinite(m["baselines"]["nearest"]["position_mae_um"])    # scene_params came through run.json
    assert "shared topology" in m["baselines"]["poly2"]["not_applicable"]

    assert evaluate.main(["--workdir", str(run), "--data", str(data / "test")]) == 0
    m2 = json.loads((run / "eval" / "test" / "metrics.json").read_text())
    assert m2["n_test"] == 2
    assert m2["position_mae_um"] == pytest.approx(m["position_mae_um"], rel=1e-5)
