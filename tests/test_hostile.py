"""Hostile inputs (issue 52): every refused command says why in one line (exit status 2), before it creates,
locks or writes anything, and leaves nothing behind; no traceback, no silent wrong answer, no stale data.
Fast (seconds each): imported synthetic trajectories, the fake solver, no training step."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from fixtures.helpers import make_synthetic_trajectory
from fixtures.synthetic import FakeSolver
from pcmgn_jax import cli, lock
from pcmgn_jax.data.cache import load_split
from pcmgn_jax.data.trajectory_io import TrajectoryFileError, trajectory_paths, write_trajectory

TRAIN = ["--preset", "tiny", "--n_train", "3", "--n_val", "1", "--n_test", "1", "--num_steps", "20",
         "--contact_radius", "20e-6", "--latent_size", "32", "--message_passing_steps", "2", "--no_progress"]


def _tree(root: Path) -> dict[str, int]:
    return {str(p.relative_to(root)): p.stat().st_mtime_ns for p in sorted(root.rglob("*"))} if root.exists() else {}


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """An imported dataset: 4 synthetic train trajectories (3 train + 1 validation), 1 test."""
    root = tmp_path_factory.mktemp("hostile_data")
    for i, d in enumerate((0.8, 0.93, 1.07, 1.2)):
        write_trajectory(make_synthetic_trajectory(d), root / "train" / f"run{i:02d}")
    write_trajectory(make_synthetic_trajectory(1.0), root / "test" / "case0")
    return root


def _refused(main, argv, capsys, *, watch: Path, match: str) -> str:
    """Run an entry point that must refuse: status 2, one line on stderr matching ``match``, ``watch``
    unchanged (nothing created, locked or written there)."""
    before = _tree(watch)
    assert cli.run(main, argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error: "), err
    assert match in err, err
    assert _tree(watch) == before
    return err


# ---- train: the whole configuration before the run folder ------------------------------------------------------
@pytest.mark.parametrize("flags, match", [
    (["--reach=attention", "--reach_heads=3"], "latent_size=32 must be divisible by reach_heads=3"),
    (["--reach=multiscale", "--reach_levels=40"], "reach_levels=40 is more than the graphs hold"),
    (["--reach_levels=3"], "--reach_levels does not apply: --reach=local"),
    (["--reach=multiscale", "--reach_heads=2"], "--reach_heads does not apply: --reach=multiscale"),
    (["--residual_ball=network"], "--residual_ball does not apply"),
    (["--process_id=1"], "--process_id does not apply"),
    (["--noise_std=-1"], "noise_std=-1.0 must be a finite number >= 0"),
    (["--lambda_pen=nan"], "lambda_pen=nan must be a finite number >= 0"),
])
def test_train_refuses_a_bad_config_before_the_run_folder_exists(data, tmp_path, capsys, flags, match):
    from experiments import train
    run = tmp_path / "run"
    _refused(train.main, [*TRAIN, f"--dataset_dir={data}", f"--workdir={run}", *flags], capsys, watch=tmp_path,
             match=match)
    assert not run.exists()


def test_multiscale_levels_are_bounded_by_the_smallest_graph(data):
    from pcmgn_jax.mgn.hierarchy import build_levels, level_sizes, shrinking_levels
    from pcmgn_jax.mgn.inputs import topology_from_trajectory
    topo = topology_from_trajectory(make_synthetic_trajectory(1.0))
    most = shrinking_levels(topo.mesh_senders, topo.mesh_receivers, topo.n_node)
    sizes = [n for n, _ in level_sizes(build_levels(topo.mesh_senders, topo.mesh_receivers, topo.n_node, most + 2))]
    assert sizes[most - 2] > sizes[most - 1] == sizes[most] == sizes[most + 1]   # shrinks to `most`, then repeats


# ---- generate: flags, counts, scenes before the dataset folder -----------------------------------------------
@pytest.mark.parametrize("flags, match", [
    (["--preset", "tiny", "--stack_split", "e2"], "--stack_split does not apply: preset 'tiny'"),
    (["--preset", "tiny", "--n_train", "-1"], "--n_train=-1: must be >= 0"),
    (["--preset", "tiny", "--low_um", "200", "--high_um", "100"], "need 0 < low < high"),
    (["--preset", "tiny", "--designs", "100,100", "--seed", "3"], "--seed does not apply: explicit designs"),
    (["--preset", "family_tiny", "--low_um", "10"], "--low_um does not apply: preset 'family_tiny'"),
    (["--pool", "a,b", "--preset", "tiny"], "--preset does not apply: --pool"),
    (["--preset", "tiny", "--merge"], "6 of 6 trajectories missing"),
])
def test_generate_refuses_before_the_dataset_folder_exists(tmp_path, capsys, monkeypatch, flags, match):
    from experiments import generate
    monkeypatch.setitem(sys.modules, "pcmgn_jax.sim.solver", FakeSolver())
    before = _tree(tmp_path)
    assert generate.main(["--out", str(tmp_path / "d"), "--no_progress", *flags]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and match in err.splitlines()[0], err
    assert _tree(tmp_path) == before


def test_a_stack_scene_with_a_zero_thickness_layer_is_refused_before_the_folder(tmp_path, capsys):
    from experiments import generate
    from pcmgn_jax.data.stack import STACK_FAMILIES, nominal
    row = dict(zip(STACK_FAMILIES["stack_tiny"].names, [nominal(("CG", "OCA1", "OCA2", "OLED", "PLATE"))[n] for n in
                                                         STACK_FAMILIES["stack_tiny"].names]))
    row["CG.thickness"] = 0.0
    text = ",".join(f"{k}={v!r}" for k, v in row.items())
    assert generate.main(["--out", str(tmp_path / "d"), "--preset", "stack_tiny", "--scene_params", text]) == 2
    err = capsys.readouterr().err
    assert "scene 1 of 1: stack scene: layer CG is present with thickness 0.0" in err.splitlines()[0], err
    assert not (tmp_path / "d").exists()


def test_a_split_of_another_plan_says_so_first():
    from pcmgn_jax.data.designs import origin_mismatch
    assert origin_mismatch({"kind": "stack", "plan": "e1", "seed": 0}, 5, {"kind": "stack", "plan": "e2", "seed": 0},
                           5) == "was generated with plan e1, asked for e2"
    assert origin_mismatch({"kind": "lhs", "seed": 0}, 4, {"kind": "lhs", "seed": 0}, 51).startswith(
        "holds 4 designs, asked for 51")


# ---- the lock: a refused command leaves no folder behind ---------------------------------------------------------
def test_a_lock_folder_made_by_a_refused_command_is_removed(tmp_path):
    new = tmp_path / "a" / "b"
    with pytest.raises(ValueError, match="refused"):
        with lock.hold(new, "test"):
            raise ValueError("refused")
    assert not (tmp_path / "a").exists()
    kept = tmp_path / "kept"
    kept.mkdir()
    with pytest.raises(ValueError):
        with lock.hold(kept, "test"):
            raise ValueError("refused")
    assert kept.is_dir()                            # a folder that was there stays (with its lock file)
    with pytest.raises(ValueError):
        with lock.hold(tmp_path / "c", "test"):
            (tmp_path / "c" / "work").write_text("x")
            raise ValueError("failed after writing")
    assert (tmp_path / "c" / "work").exists()       # what a command wrote is never removed


# ---- the cache: a file edited in place, size and modification time kept ----------------------------------------
def test_a_trajectory_edited_in_place_with_the_same_size_and_mtime_is_not_trained_on(tmp_path):
    stem = tmp_path / "train" / "run00"
    write_trajectory(make_synthetic_trajectory(1.0), stem)
    first = load_split(tmp_path, "train")[0]
    h5 = trajectory_paths(stem)[1]
    st = h5.stat()
    found = []
    with h5py.File(h5, "r") as f:      # the last float array written (a field of the last frame)
        f.visititems(lambda n, o: found.append((o.id.get_offset(), o.dtype))
                     if isinstance(o, h5py.Dataset) and o.dtype.kind == "f" and o.size > 8 else None)
    offset, dtype = found[-1]
    assert offset is not None                        # contiguous: the bytes can be changed in place
    with open(h5, "r+b") as f:
        f.seek(offset + dtype.itemsize * 7)
        f.write(np.array([1.0], dtype).tobytes())
    os.utime(h5, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert h5.stat().st_size == st.st_size and h5.stat().st_mtime_ns == st.st_mtime_ns
    with pytest.raises(TrajectoryFileError, match="does not match"):
        load_split(tmp_path, "train")                # rebuilt, and the rebuild refuses the file by name
    assert first.meta["source_sha256"]
