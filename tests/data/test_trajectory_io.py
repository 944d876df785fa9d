"""Trajectory files: exact round trip, atomic writes, refusal of partial/corrupt files."""
from __future__ import annotations

import json
import shutil

import h5py
import meshio
import numpy as np
import pytest

from fixtures.synthetic import assert_same, synthetic_trajectory
from pcmgn_jax.data import trajectory_io as tio


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_round_trip_exact(tmp_path, dtype):
    traj = synthetic_trajectory(dtype=dtype, meta={"energy": {"max_rel_drift": 1e-3}})
    digest = tio.write_trajectory(traj, tmp_path / "a")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5", "a.json", "a.xdmf"]
    back = tio.read_trajectory(tmp_path / "a")
    assert_same(traj, back)
    assert back.meta["energy"] == {"max_rel_drift": 1e-3}
    assert back.meta["source"] == "solver" and back.meta["units"]["stress"] == "Pa"
    side = json.loads((tmp_path / "a.json").read_text())
    assert side["sha256"] == digest == tio.content_hash(back)
    assert side["n_nodes"] == traj.n_nodes and side["n_frames"] == 4 and len(side["times"]) == 4
    for key in tio.STANDARD_KEYS:
        assert key in side


def test_plain_meshio_reader_and_3_component_vectors(tmp_path):
    traj = synthetic_trajectory()
    tio.write_trajectory(traj, tmp_path / "a")
    with meshio.xdmf.TimeSeriesReader(tmp_path / "a.xdmf") as r:
        pts, cells = r.read_points_cells()
        assert cells[0].type == "quad" and pts.shape == (traj.n_nodes, 3)
        t, pd, cd = r.read_data(2)
    assert t == traj.times[2]
    assert pd["displacement"].shape == (traj.n_nodes, 3)
    np.testing.assert_array_equal(pd["displacement"][:, :2], traj.displacement[2])
    np.testing.assert_array_equal(cd["part"][0], traj.cell_part)


def test_h5_named_relative_and_folder_move(tmp_path):
    traj = synthetic_trajectory()
    tio.write_trajectory(traj, tmp_path / "d1" / "run.7")   # dot in name: stem stays 'run.7'
    text = (tmp_path / "d1" / "run.7.xdmf").read_text()
    assert "run.7.h5:/" in text and str(tmp_path) not in text and ".tmp-" not in text
    shutil.move(tmp_path / "d1", tmp_path / "moved")
    assert_same(traj, tio.read_trajectory(tmp_path / "moved" / "run.7.xdmf"))


def test_write_does_not_depend_on_cwd(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    tio.write_trajectory(synthetic_trajectory(), tmp_path / "sub" / "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sub"]


def test_missing_sidecar_refused(tmp_path):
    tio.write_trajectory(synthetic_trajectory(), tmp_path / "a")
    (tmp_path / "a.json").unlink()
    with pytest.raises(tio.TrajectoryFileError, match=r"a\.json: sidecar missing"):
        tio.read_trajectory(tmp_path / "a")


def test_hash_mismatch_refused(tmp_path):
    tio.write_trajectory(synthetic_trajectory(), tmp_path / "a")
    with h5py.File(tmp_path / "a.h5", "r+") as f:
        names = sorted(f.keys(), key=lambda s: int(s[4:]))
        ds = f[names[3]]      # first frame's displacement
        ds[0, 0] = ds[0, 0] + 1e-9
    with pytest.raises(tio.TrajectoryFileError, match=r"a\.json: field 'sha256' does not match"):
        tio.read_trajectory(tmp_path / "a")
    tio.read_trajectory(tmp_path / "a", verify=False)   # shape checks still pass


def test_sidecar_disagrees(tmp_path):
    tio.write_trajectory(synthetic_trajectory(), tmp_path / "a")
    side = json.loads((tmp_path / "a.json").read_text())
    side["times"][1] += 1e-7
    (tmp_path / "a.json").write_text(json.dumps(side))
    with pytest.raises(tio.TrajectoryFileError, match="field 'times' disagrees"):
        tio.read_trajectory(tmp_path / "a")
    side["times"][1] -= 1e-7
    side["n_nodes"] += 1
    (tmp_path / "a.json").write_text(json.dumps(side))
    with pytest.raises(tio.TrajectoryFileError, match="n_nodes"):
        tio.read_trajectory(tmp_path / "a")


def test_missing_h5_named(tmp_path):
    tio.write_trajectory(synthetic_trajectory(), tmp_path / "a")
    (tmp_path / "a.h5").unlink()
    with pytest.raises(tio.TrajectoryFileError, match=r"a\.h5: file missing"):
        tio.read_trajectory(tmp_path / "a")


def test_overwrite_and_crash_leaves_no_valid_partial(tmp_path, monkeypatch):
    t1, t2 = synthetic_trajectory(seed=1), synthetic_trajectory(seed=2)
    tio.write_trajectory(t1, tmp_path / "a")
    # simulate a kill after the HDF5 was replaced but before the sidecar commit
    real_replace = tio.os.replace
    calls = []

    def dying_replace(src, dst):
        calls.append(dst)
        if str(dst).endswith(".xdmf"):
            raise KeyboardInterrupt("killed")
        real_replace(src, dst)

    monkeypatch.setattr(tio.os, "replace", dying_replace)
    with pytest.raises(KeyboardInterrupt):
        tio.write_trajectory(t2, tmp_path / "a")
    monkeypatch.setattr(tio.os, "replace", real_replace)
    assert not any(p.name.startswith(".a.tmp") for p in tmp_path.iterdir())
    with pytest.raises(tio.TrajectoryFileError, match="sidecar missing"):
        tio.read_trajectory(tmp_path / "a")
    tio.write_trajectory(t2, tmp_path / "a")
    assert_same(t2, tio.read_trajectory(tmp_path / "a"))


def test_invalid_input_writes_nothing(tmp_path):
    traj = synthetic_trajectory()
    traj.von_mises[1, 3] = np.nan
    with pytest.raises(ValueError, match="'von_mises' has a non-finite value"):
        tio.write_trajectory(traj, tmp_path / "a")
    traj = synthetic_trajectory(meta={"sha256": "x"})
    with pytest.raises(ValueError, match="reserved"):
        tio.write_trajectory(traj, tmp_path / "a")
    traj = synthetic_trajectory(meta={"energy": {"drift": object()}})
    with pytest.raises(ValueError, match="energy.drift: value of type object"):
        tio.write_trajectory(traj, tmp_path / "a")
    assert list(tmp_path.iterdir()) == []


def test_nonfinite_meta_becomes_null(tmp_path):
    traj = synthetic_trajectory(meta={"phases": {"separation_s": float("nan")}, "n": np.int64(3)})
    tio.write_trajectory(traj, tmp_path / "a")
    assert tio.read_trajectory(tmp_path / "a").meta["phases"] == {"separation_s": None}
