"""Dataset generation: LHS designs, --designs parsing, resumable generation with a fake solver."""
from __future__ import annotations

import json
import sys

import h5py
import meshio
import numpy as np
import pytest

from fixtures.synthetic import FakeSolver
from pcmgn_jax.data import dataset as ds
from pcmgn_jax.data.trajectory_io import read_trajectory


@pytest.fixture
def fake(monkeypatch):
    mod = FakeSolver()
    monkeypatch.setitem(sys.modules, "pcmgn_jax.sim.solver", mod)
    return mod


def test_lhs_designs_stratified_and_seeded():
    d = ds.lhs_designs(10, seed=3)
    assert d.shape == (10, 2) and d.dtype == np.float64
    assert np.all((d >= 50e-6) & (d <= 150e-6))
    for j in range(2):   # one point per stratum in every dimension
        bins = np.floor((d[:, j] - 50e-6) / 10e-6).astype(int)
        assert sorted(bins) == list(range(10))
    np.testing.assert_array_equal(d, ds.lhs_designs(10, seed=3))
    assert not np.allclose(d, ds.lhs_designs(10, seed=4))


def test_parse_designs():
    np.testing.assert_allclose(ds.parse_designs("40,40;40,160"), [[40e-6, 40e-6], [40e-6, 160e-6]])
    np.testing.assert_allclose(ds.parse_designs(" 50 , 60 ; "), [[50e-6, 60e-6]])
    for bad, msg in [("", "empty"), ("40,x", "design 1 .* not a list of numbers"),
                     ("40,40;40", "design 2 .* has 1 values, expected 2"), ("40,-1", "> 0"),
                     ("40,nan", "finite")]:
        with pytest.raises(ValueError, match=msg):
            ds.parse_designs(bad)


def test_generate_resume_and_manifest(tmp_path, fake, capsys):
    out = tmp_path / "data"
    ds.ensure_dataset(out, preset="tiny", n_train=3, n_test=2, seed=0, batch=2, progress=True)
    assert "design/s" in capsys.readouterr().err
    assert [len(c[1]) for c in fake.calls] == [2, 2, 1] and fake.calls[0][0] == "tiny"
    man = json.loads((out / "manifest.json").read_text())
    assert set(man["splits"]) == {"train", "test"}
    tr = man["splits"]["train"]["trajectories"]
    assert [e["name"] for e in tr] == ["train_0000", "train_0001", "train_0002"]
    lhs = ds.lhs_designs(5, seed=0)
    np.testing.assert_allclose([e["design_m"] for e in tr], lhs[:3])
    np.testing.assert_allclose(man["splits"]["test"]["trajectories"][1]["design_um"], lhs[4] * 1e6)
    assert all(len(e["sha256"]) == 64 and e["wall_time_s"] == 0.5 for e in tr)
    # plain meshio reads it
    with meshio.xdmf.TimeSeriesReader(out / "train" / "train_0001.xdmf") as r:
        r.read_points_cells()
        assert r.num_steps == 4
    # resume: nothing to do
    fake.calls.clear()
    ds.ensure_dataset(out, preset="tiny", n_train=3, n_test=2, seed=0, batch=2, progress=False)
    assert fake.calls == []
    # a corrupted and a half-written trajectory are regenerated, nothing else
    with h5py.File(out / "train" / "train_0001.h5", "r+") as f:
        f["data5"][0] = -1.0      # a von Mises value of frame 0
    (out / "test" / "test_0000.json").unlink()
    ds.ensure_dataset(out, preset="tiny", n_train=3, n_test=2, seed=0, batch=8, progress=False)
    assert len(fake.calls) == 1 and len(fake.calls[0][1]) == 2
    read_trajectory(out / "train" / "train_0001")
    assert ds.split_stems(out, "test")[0] == out / "test" / "test_0000"


def test_extra_split_and_conflicts(tmp_path, fake):
    out = tmp_path / "d"
    ds.ensure_dataset(out, preset="tiny", n_train=2, n_test=1, seed=0, progress=False)
    ds.ensure_dataset(out, preset="tiny", designs=ds.parse_designs("40,40;160,160"), progress=False)
    man = ds.load_manifest(out)
    assert man["splits"]["extrap"]["trajectories"][1]["design_um"] == [160.0, 160.0]
    assert set(man["splits"]) == {"train", "test", "extrap"}
    with pytest.raises(ds.DatasetError, match="preset 'tiny', not 'cpu'"):
        ds.ensure_dataset(out, preset="cpu", n_train=2, n_test=1, seed=0, progress=False)
    with pytest.raises(ds.DatasetError, match="split 'train' was generated with seed 0, asked for 1; use another"):
        ds.ensure_dataset(out, preset="tiny", n_train=2, n_test=1, seed=1, progress=False)
    with pytest.raises(ds.DatasetError, match="shape"):
        ds.ensure_dataset(out, preset="tiny", designs=np.ones((2, 3)) * 1e-4, progress=False)


def test_solver_error_isolated(tmp_path, monkeypatch):
    mod = FakeSolver(fail_above=100e-6)
    monkeypatch.setitem(sys.modules, "pcmgn_jax.sim.solver", mod)
    out = tmp_path / "d"
    with pytest.raises(ds.DatasetError, match=r"(?s)1 design\(s\) failed.*extrap_0001"):
        ds.ensure_dataset(out, preset="tiny", designs=ds.parse_designs("60,60;120,60;70,70"),
                          batch=3, progress=False)
    man = ds.load_manifest(out)
    ent = man["splits"]["extrap"]["trajectories"]
    assert ent[0]["sha256"] and ent[2]["sha256"] and ent[1]["sha256"] is None
    assert "energy drift" in ent[1]["error"]
    assert not (out / "extrap" / "extrap_0001.json").exists()


def test_cli(tmp_path, fake, capsys):
    from experiments.generate import main

    out = tmp_path / "cli"
    assert main(["--out", str(out), "--preset", "tiny", "--n_train", "2", "--n_test", "1",
                 "--no_progress"]) == 0
    assert main(["--out", str(out), "--preset", "tiny", "--designs", "40,40;40,160", "--split",
                 "extrap", "--no_progress"]) == 0
    assert len(ds.split_stems(out, "extrap")) == 2
    assert main(["--out", str(out), "--preset", "tiny", "--designs", "40,x"]) == 2
    assert "not a list of numbers" in capsys.readouterr().err


def test_family_scenes_outside_its_box_from_scene_params(tmp_path, fake, capsys):
    """A scene family takes explicit scene-parameter rows (SI, family order) into a named split, outside
    its box too; each scene is solved with its own parameters, recorded in the manifest and the meta."""
    from experiments import generate
    names = ds.FAMILIES["family_tiny"].names
    text = ("ball.radius=3.5e-3,ball.velocity=0.8,OCA1=40e-6,OCA2=160e-6,POL=25e-6;"
            "POL=75e-6,OCA2=40e-6,OCA1=160e-6,ball.velocity=0.45,ball.radius=6.5e-3")
    rows = ds.parse_scene_params(text, names)
    np.testing.assert_allclose(rows, [[3.5e-3, 0.8, 40e-6, 160e-6, 25e-6], [6.5e-3, 0.45, 160e-6, 40e-6, 75e-6]])
    out = tmp_path / "fx"
    assert generate.main(["--preset", "family_tiny", "--out", str(out), "--scene_params", text, "--no_progress"]) == 0
    man = ds.load_manifest(out)
    entries = man["splits"]["extrap"]["trajectories"]
    assert [e["scene_params"]["ball.radius"] for e in entries] == [3.5e-3, 6.5e-3]
    assert entries[1]["design_um"] == [160.0, 40.0, 75.0]            # OCA1, OCA2, POL: the design layers
    assert [tuple(np.round(c[1][0] * 1e6, 3)) for c in fake.calls] == [(40.0, 160.0, 25.0), (160.0, 40.0, 75.0)]
    traj = read_trajectory(out / entries[0]["path"])
    assert traj.meta["scene_params"] == entries[0]["scene_params"] and traj.meta["family"] == "family_tiny"
    for bad, msg in [("ball.radius=3e-3", r"scene 1 misses \['OCA1'"),
                     ("ball.radius=3e-3,ball.radius=4e-3", "repeated"), ("mass=1", "unknown"),
                     ("ball.radius=-1", "> 0"), ("ball.radius", "not NAME=VALUE"), (";", "empty")]:
        with pytest.raises(ValueError, match=msg):
            ds.parse_scene_params(bad, names)
    capsys.readouterr()
    assert generate.main(["--preset", "family_tiny", "--out", str(out), "--designs", "40,40,40"]) == 2
    assert "scene family; give its scenes with --scene_params" in capsys.readouterr().err
    assert generate.main(["--preset", "tiny", "--out", str(tmp_path / "t"), "--scene_params", text]) == 2
    assert "--scene_params needs a scene-family preset" in capsys.readouterr().err


def test_a_smaller_run_reads_the_first_rows_of_a_larger_dataset(tmp_path, fake):
    """prepare_dataset on a complete LHS dataset of the same preset and seed with more trajectories than
    asked for: no solver call, no rewrite; load_splits then gives its first rows. Another seed is still
    the manifest's named conflict."""
    from pcmgn_jax.data.splits import load_splits, prepare_dataset
    out = tmp_path / "d"
    ds.ensure_dataset(out, preset="tiny", n_train=4, n_test=2, seed=0, progress=False)
    calls, before = len(fake.calls), (out / "manifest.json").stat().st_mtime_ns
    assert prepare_dataset(out, preset="tiny", n_train=2, n_test=1, seed=0) == (out, ds.GENERATE)
    assert len(fake.calls) == calls and (out / "manifest.json").stat().st_mtime_ns == before
    train, val, test = load_splits(out, n_train=1, n_val=1, n_test=1)
    assert [t.meta["name"] for t in train + val + test] == ["train_0000", "train_0001", "test_0000"]
    with pytest.raises(ds.DatasetError, match="split 'train' was generated with seed 0, asked for 1"):
        prepare_dataset(out, preset="tiny", n_train=2, n_test=1, seed=1)
