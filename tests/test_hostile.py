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
    (["--reach=attention", "--reach_slices=5000"], "reach_slices=5000 is more than the graphs hold"),
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


# ---- numbers out of range, flags that do not apply, paths: one line, before anything runs ----------------------
@pytest.mark.parametrize("command, argv, match", [
    ("hertz_check", ["--elems_per_radius", "0"], "--elems_per_radius=0.0: must be >= 1"),
    ("hertz_check", ["--velocity", "inf"], "--velocity=inf: must be a finite number"),
    ("panel_report", ["--preset", "tiny", "--frames", "0"], "--frames=0: must be >= 2"),
    ("explore", ["--workdir", "RUN", "--port", "99999"], "--port=99999: must be <= 65535"),
    ("optimize", ["--workdir", "RUN", "--pop", "0"], "--pop=0: must be >= 2"),
    ("explore", ["--workdir", "RUN", "--no_mgn", "--mgn_spread"], "--mgn_spread does not apply: --no_mgn"),
    ("optimize", ["--workdir", ""], "--workdir is empty: give a path"),
    ("generate", ["--out", " ", "--preset", "tiny"], "--out is empty: give a path"),
    ("optimize", ["--workdir", "RUN", "--method", "gradient", "--pop", "8"], "--pop does not apply: --method gradient"),
    ("optimize", ["--workdir", "RUN", "--surrogate", "kriging", "--ensemble", "a,b"], "--ensemble does not apply"),
    ("optimize", ["--workdir", "RUN", "--iters", "3"], "--iters does not apply: --method ga"),
    ("objective_convergence", ["--meshes", "cpu,bogus", "--out", "OUT"], "mesh 'bogus': unknown mesh preset"),
    ("mesh_series", ["--meshes", "tiny@x", "--out", "OUT"], "mesh 'tiny@x'"),
    ("evaluate", ["--workdir", "RUN", "--split", "bogus"], "invalid choice 'bogus' for argument '--split'"),
])
def test_entry_points_refuse_bad_numbers_and_flags_in_one_line(tmp_path, capsys, command, argv, match):
    import importlib
    argv = [a.replace("RUN", str(tmp_path / "run")).replace("OUT", str(tmp_path / "out")) for a in argv]
    _refused(importlib.import_module(f"experiments.{command}").main, argv, capsys, watch=tmp_path, match=match)


def test_every_bounds_entry_is_a_flag_of_its_command():
    import dataclasses
    import importlib

    from experiments.console import COMMANDS
    for name in COMMANDS:
        for v in vars(importlib.import_module(f"experiments.{name}")).values():
            if isinstance(v, type) and dataclasses.is_dataclass(v) and "BOUNDS" in vars(v):
                assert set(v.BOUNDS) <= {f.name for f in dataclasses.fields(v)}, (name, v.BOUNDS)


def test_a_path_error_is_one_line_not_a_traceback(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")

    def main(argv):
        (blocker / "out").mkdir(parents=True)
    assert cli.run(main, []) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error: ") and str(blocker) in err, err


def _config_only_run(root: Path, data: Path, **kw) -> Path:
    from fixtures.helpers import tiny_config
    run = root / "run"
    run.mkdir()
    tiny_config(dataset_dir=str(data), n_train=3, n_val=1, n_test=1, **kw).save_json(run / "config.json")
    return run


def test_active_checks_its_budget_before_any_folder_or_solver_run(data, tmp_path, capsys):
    from experiments import active
    run = _config_only_run(tmp_path, data)
    _refused(active.main, ["--workdir", str(run), "--budget", "2", "--n_init", "4"], capsys, watch=tmp_path,
             match="budget 2 is below round 0's 4 designs")


@pytest.mark.parametrize("kw, match", [
    (dict(name="../../x"), "must be one folder name"),
    (dict(residual_ball="network"), "is for a run with residual_of"),
])
def test_evaluate_refuses_a_name_outside_the_run_and_a_ball_it_cannot_move(data, tmp_path, monkeypatch, kw, match):
    from pcmgn_jax.eval import pipeline
    from pcmgn_jax.mgn import checkpoint
    run = _config_only_run(tmp_path, data)
    monkeypatch.setattr(checkpoint, "require_run", lambda *a, **k: run)   # the checks come before the model
    before = _tree(tmp_path)
    with pytest.raises(ValueError, match=match):
        pipeline.run(run, **kw)
    assert _tree(tmp_path) == before


@pytest.mark.parametrize("command, flag", [("tasks_table", "--task=a"), ("learning_curve", "--point=8")])
def test_a_json_that_is_no_evaluation_is_refused_not_tabled_as_unmeasured(tmp_path, capsys, command, flag):
    import importlib
    odd = tmp_path / "odd.json"
    odd.write_text('{"a": 1}')
    _refused(importlib.import_module(f"experiments.{command}").main, [f"{flag}={odd}", "--out", str(tmp_path / "o")],
             capsys, watch=tmp_path, match=f"{odd} is not a metrics.json of experiments.evaluate")
