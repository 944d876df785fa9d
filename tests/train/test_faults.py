"""Fault injection (issue 41): what a kill, a second writer, a damaged checkpoint or cache, a changed manifest
and a bad input file do to tiny runs. Each test asserts that the run resumes to the uninterrupted result or
stops with a named error, and that nothing earlier is lost (docs/reliability.md)."""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

from fixtures.helpers import ROOT, make_synthetic_trajectory, tiny_config
from pcmgn_jax import cli, lock
from pcmgn_jax.data import dataset as ds, splits
from pcmgn_jax.data.trajectory_io import TrajectoryFileError, trajectory_paths, write_trajectory
from pcmgn_jax.mgn import checkpoint
from pcmgn_jax.train import loop as training
from pcmgn_jax.train.resume import cut_metrics

# a tiny run on the synthetic imported dataset below: 20 steps, a checkpoint and a validation every 10
TRAIN_FLAGS = ["--preset", "tiny", "--n_train", "3", "--n_val", "1", "--n_test", "1", "--num_steps", "20",
               "--steps_per_dispatch", "10", "--log_every", "10", "--ckpt_every", "10", "--val_every", "10",
               "--contact_radius", "20e-6", "--latent_size", "32", "--message_passing_steps", "2", "--no_progress"]


def _tree(root: Path) -> dict[str, int]:
    return {str(p.relative_to(root)): p.stat().st_mtime_ns for p in sorted(root.rglob("*"))} if root.exists() else {}


def _imported(root: Path) -> Path:
    """A dataset without a manifest: 4 synthetic train trajectories (3 train + 1 validation), 1 test."""
    for i, d in enumerate((0.8, 0.93, 1.07, 1.2)):
        write_trajectory(make_synthetic_trajectory(d), root / "train" / f"run{i:02d}")
    write_trajectory(make_synthetic_trajectory(1.0), root / "test" / "case0")
    return root


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return _imported(tmp_path_factory.mktemp("faults_data"))


def _fake_run(run: Path) -> dict[str, str]:
    """A folder that looks like a finished run (its files' content, to check that nothing is lost)."""
    (run / "checkpoints" / "best").mkdir(parents=True)
    files = {"config.json": json.dumps(tiny_config().to_dict()), "metrics.jsonl": '{"step": 10, "loss": 1.0}\n',
             "checkpoints/best/note": "kept"}
    for name, text in files.items():
        (run / name).write_text(text)
    return files


# ---- a second train on a workdir ----------------------------------------------------------------------------
def test_second_train_without_resume_is_refused_and_nothing_is_lost(data, tmp_path, capsys, monkeypatch):
    from experiments import train
    run = tmp_path / "run"
    files = _fake_run(run)
    before = _tree(tmp_path)
    monkeypatch.setattr(ds, "ensure_dataset", lambda *a, **k: pytest.fail("nothing may be generated"))
    rc = cli.run(train.main, [*TRAIN_FLAGS, f"--dataset_dir={data}", f"--workdir={run}"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert str(run) in err and "--resume" in err and "--overwrite" in err
    assert _tree(tmp_path) == before
    assert all((run / n).read_text() == t for n, t in files.items())


def test_overwrite_moves_the_earlier_run_aside_and_trains(data, tmp_path, capsys, monkeypatch):
    from experiments import train
    from pcmgn_jax.train import pipeline
    run = tmp_path / "run"
    files = _fake_run(run)
    seen = []

    def fake_training(cfg, workdir, data, *, resume):   # the training itself is covered elsewhere: what it finds
        seen.append(sorted(p.name for p in workdir.iterdir()))
        return dict(step=0, seconds=0.0, best_val=float("nan"))
    monkeypatch.setattr(pipeline, "_run_locked", fake_training)
    assert cli.run(train.main, [*TRAIN_FLAGS, f"--dataset_dir={data}", f"--workdir={run}", "--overwrite"]) == 0
    out = capsys.readouterr().out
    (old,) = [p for p in tmp_path.iterdir() if p.name.startswith("run.old-")]
    assert f"moved the earlier run in {run} to {old}" in out
    assert all((old / n).read_text() == t for n, t in files.items())            # the earlier run, whole
    assert seen == [[".lock"]]                                                   # the new one starts empty
    assert cli.run(train.main, [f"--workdir={old}", "--resume", "--overwrite"]) == 2
    assert "exclude each other" in capsys.readouterr().err


# ---- one writer per folder ----------------------------------------------------------------------------------
HOLDER = ("import sys, time\nfrom pcmgn_jax.lock import hold\nwith hold(sys.argv[1], 'holder'):\n"
          "    print('held', flush=True)\n    time.sleep(60)\n")


def _holder(folder: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], stdout=subprocess.PIPE, text=True,
                            cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_writer_is_refused_while_the_first_holds_the_lock(data, tmp_path, capsys):
    from experiments import generate, train
    run, out = tmp_path / "run", tmp_path / "gen"
    holders = [_holder(run), _holder(out)]
    try:
        rc = cli.run(train.main, [*TRAIN_FLAGS, f"--dataset_dir={data}", f"--workdir={run}"])
        err = capsys.readouterr().err
        assert rc == 2 and f"{run} is in use by pid {holders[0].pid} on host {socket.gethostname()}" in err, err
        assert "holder" in err and sorted(p.name for p in run.iterdir()) == [".lock"]   # nothing written
        assert generate.main(["--preset", "tiny", "--out", str(out), "--designs", "60,60", "--no_progress"]) == 2
        assert f"{out} is in use by pid {holders[1].pid}" in capsys.readouterr().err
    finally:
        for p in holders:
            p.kill()
            p.wait()
    with lock.hold(run, "train"):      # the holder is gone: the lock is free again (the kernel released it)
        pass


def test_a_stale_lock_is_named_and_taken_over(tmp_path, capsys):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / ".lock").write_text(json.dumps({"pid": dead.pid, "host": socket.gethostname(),
                                                "command": "train: killed", "since": "earlier"}))
    with lock.hold(tmp_path, "train"):
        assert lock.read_holder(tmp_path)["pid"] == os.getpid()
    err = capsys.readouterr().err
    assert f"stale lock of pid {dead.pid} on host {socket.gethostname()}" in err and "no longer running" in err
    assert lock.read_holder(tmp_path) is None          # released cleanly: no stale record left
    with lock.hold(tmp_path, "train"):
        pass
    assert "stale" not in capsys.readouterr().err


# ---- checkpoints a kill cannot break -------------------------------------------------------------------------
def _cfg():
    return tiny_config(num_steps=60, steps_per_dispatch=10, log_every=10, ckpt_every=20, val_every=20)


@pytest.fixture(scope="module")
def reference(tiny_trajs, tmp_path_factory):
    """The uninterrupted run of :func:`_cfg`: (workdir, summary)."""
    workdir = tmp_path_factory.mktemp("faults_ref")
    return workdir, training.train(_cfg(), workdir, train_trajs=tiny_trajs[:3], val_trajs=tiny_trajs[3:])


def _steps_logged(workdir: Path) -> list[int]:
    return [json.loads(line)["step"] for line in (workdir / "metrics.jsonl").read_text().splitlines()]


def _assert_same_run(workdir: Path, res: dict, reference) -> None:
    ref_dir, ref = reference
    assert res["step"] == ref["step"] == 60
    for a, b in zip(jax.tree.leaves(res["state"].params), jax.tree.leaves(ref["state"].params)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert _steps_logged(workdir) == _steps_logged(ref_dir)        # every step once, in order
    assert checkpoint.steps(workdir / "checkpoints" / "best") == checkpoint.steps(ref_dir / "checkpoints" / "best")
    assert res["best_val"] == ref["best_val"]


@pytest.mark.slow   # 22 s; the other kill and resume tests here run by default
def test_a_kill_between_the_best_and_the_periodic_checkpoint_resumes(tiny_trajs, tmp_path, reference, capsys):
    """Killed at step 40 after best/40 was written, before periodic/40: resume from 20 writes best/40 again."""
    trajs = dict(train_trajs=tiny_trajs[:3], val_trajs=tiny_trajs[3:])
    training.train(_cfg(), tmp_path, stop_after=40, **trajs)
    assert checkpoint.steps(tmp_path / "checkpoints" / "best") == [40]   # this run's validation at 40 was its best
    shutil.rmtree(tmp_path / "checkpoints" / "periodic" / "40")
    with open(tmp_path / "metrics.jsonl", "a") as f:
        f.write('{"step": 50, "loss": 0.1')                               # and a line cut by the kill
    res = training.train(_cfg(), tmp_path, resume=True, **trajs)
    err = capsys.readouterr().err
    assert "removed checkpoint(s) [40] written after step 20" in err and "after step 20 removed" in err
    _assert_same_run(tmp_path, res, reference)


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # orbax's loop after the failed read
@pytest.mark.slow  # ~47 s (two tiny trainings); the other checkpoint-fault tests here run by default
def test_a_damaged_newest_checkpoint_is_named_and_the_previous_one_used(tiny_trajs, tmp_path, reference, capsys):
    trajs = dict(train_trajs=tiny_trajs[:3], val_trajs=tiny_trajs[3:])
    training.train(_cfg(), tmp_path, stop_after=40, **trajs)
    periodic = tmp_path / "checkpoints" / "periodic"
    (periodic / "40" / "state" / "manifest.ocdbt").unlink()                # a file missing inside it
    (periodic / "60.orbax-checkpoint-tmp-1").mkdir()                       # a save the kill cut short
    res = training.train(_cfg(), tmp_path, resume=True, **trajs)
    err = capsys.readouterr().err
    assert f"checkpoint {periodic / '40'} is damaged" in err and "using the previous one" in err
    assert (tmp_path / "checkpoints" / "damaged" / "periodic-40" / "state").is_dir()   # set aside, not deleted
    assert not any("tmp" in p.name for p in periodic.iterdir())
    _assert_same_run(tmp_path, res, reference)


def test_cut_metrics_keeps_the_lines_up_to_the_step(tmp_path):
    log = tmp_path / "metrics.jsonl"
    log.write_text('{"step": 10}\n{"step": 20}\n{"step": 30}{"step": 20, "x": 1}\n{"step": 30}\n')
    assert cut_metrics(log, 20) == 2
    assert log.read_text() == '{"step": 10}\n{"step": 20}\n'


# ---- caches that cannot lie ----------------------------------------------------------------------------------
def _h5_nan(stem: Path) -> None:
    import h5py
    with h5py.File(trajectory_paths(stem)[1], "r+") as f:
        names = []
        f.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) and o.dtype.kind == "f"
                     and o.ndim == 1 else None)
        ds_ = f[names[-1]]
        ds_[0] = np.nan


@pytest.mark.parametrize("damage", ["truncate", "nan"])
def test_a_damaged_trajectory_behind_a_built_cache_is_caught(tmp_path, damage):
    root = _imported(tmp_path / "data")
    splits.load_splits(root, n_train=3, n_val=1, n_test=0)                     # the cache is built
    stem = root / "train" / "run01"
    if damage == "truncate":
        h5 = trajectory_paths(stem)[1]
        os.truncate(h5, h5.stat().st_size // 2)
    else:
        _h5_nan(stem)
    with pytest.raises(TrajectoryFileError, match="run01"):
        splits.load_splits(root, n_train=3, n_val=1, n_test=0)


def test_a_changed_manifest_entry_is_caught(tmp_path, monkeypatch):
    from fixtures.synthetic import FakeSolver
    monkeypatch.setitem(sys.modules, "pcmgn_jax.sim.solver", FakeSolver())
    root = ds.ensure_dataset(tmp_path / "gen", preset="tiny", n_train=3, n_test=1, progress=False)
    assert len(splits.load_splits(root, n_train=2, n_val=1, n_test=1)[0]) == 2
    man = json.loads((root / "manifest.json").read_text())
    man["splits"]["train"]["trajectories"][1]["design_m"][0] *= 1.5
    (root / "manifest.json").write_text(json.dumps(man))
    with pytest.raises(ds.DatasetError, match=r"entry 'train_0001' disagrees with .*train_0001.json \(design_m"):
        splits.load_splits(root, n_train=2, n_val=1, n_test=1)


# ---- inputs and entry points ---------------------------------------------------------------------------------
@pytest.mark.parametrize("name,text", [("empty.toml", ""), ("blank.toml", "  \n\t\n"), ("comments.toml", "# a\n"),
                                       ("empty.json", ""), ("braces.json", "{}")])
def test_an_empty_scene_file_is_refused(tmp_path, capsys, monkeypatch, name, text):
    from experiments import generate
    scene = tmp_path / name
    scene.write_text(text)
    monkeypatch.setattr(generate, "ensure_dataset", lambda *a, **k: pytest.fail("the paper's scene was used"))
    out = tmp_path / "out"
    assert generate.main(["--preset", "tiny", "--out", str(out), "--scene", str(scene), "--no_progress"]) == 2
    assert f"{scene}: empty scene file" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize("text", ["", "  \n", "{not json"])
def test_an_empty_or_broken_run_config_is_named(tmp_path, text):
    from pcmgn_jax.config import TrainConfig
    (tmp_path / "config.json").write_text(text)
    with pytest.raises(ValueError, match=f"{tmp_path / 'config.json'}: not a run config"):
        TrainConfig.load(tmp_path / "config.json")


@pytest.mark.parametrize("command", ["evaluate", "optimize", "explore"])
@pytest.mark.parametrize("what", ["missing", "file", "no_checkpoint"])
def test_an_entry_point_answers_a_bad_run_with_one_line_and_writes_nothing(tmp_path, capsys, command, what):
    import importlib
    run = tmp_path / "run"
    if what == "file":
        run.write_text("x")
    elif what == "no_checkpoint":
        run.mkdir()
        tiny_config(dataset_dir=str(tmp_path / "nodata")).save_json(run / "config.json")
    before = _tree(tmp_path)
    module = importlib.import_module(f"experiments.{command}")
    mgn = ["--surrogate", "mgn"] if command == "optimize" else []   # optimize's default (kriging) needs no checkpoint
    assert cli.run(module.main, ["--workdir", str(run), *mgn]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(run) in err and f"experiments.train --workdir {run}" in err, err
    assert {"missing": "no such run folder", "file": "is a file", "no_checkpoint": "holds no checkpoint"}[what] in err
    assert _tree(tmp_path) == before


# ---- a kill at a random moment (slow: subprocesses, the solver) ----------------------------------------------
def _kill_when(cmd: list[str], started, delay: float) -> int:
    """Run ``cmd``; once ``started()`` is true (the work has begun), wait ``delay`` s and SIGKILL it (if it
    has not finished by then). Returns its exit status (-9 when killed)."""
    proc = subprocess.Popen(cmd, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    while proc.poll() is None and not started():
        time.sleep(0.05)
    try:
        return proc.wait(timeout=delay)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
        return proc.wait()


@pytest.mark.slow  # ~15-30 s: two tiny generations with the solver, one killed
@pytest.mark.parametrize("seed", [0])
def test_generate_killed_at_a_random_moment_resumes_to_the_same_dataset(tmp_path, seed):
    from experiments import generate
    args = ["--preset", "tiny", "--designs", "60,60;90,80;120,140;140,60", "--batch", "1", "--no_progress"]
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert generate.main([*args, "--out", str(whole)]) == 0
    delay = np.random.default_rng(seed).uniform(0.0, 1.5)      # [s] after the first trajectory is written
    rc = _kill_when([sys.executable, "-m", "experiments.generate", *args, "--out", str(cut)],
                    lambda: any((cut / "extrap").glob("*.json")), delay)
    print(f"killed: rc={rc}, trajectories written {len(list((cut / 'extrap').glob('*.json')))}")
    assert generate.main([*args, "--out", str(cut)]) == 0
    def sha(root):
        splits = json.loads((root / "manifest.json").read_text())["splits"]
        return [e["sha256"] for e in splits["extrap"]["trajectories"]]
    assert sha(cut) == sha(whole) and all(sha(whole))


@pytest.mark.slow  # ~45 s each: a training in process, one killed in a subprocess, its resume
@pytest.mark.parametrize("seed", [0, 1])
def test_train_killed_at_a_random_moment_resumes_to_the_same_parameters(data, tmp_path, seed):
    from experiments import train
    flags = [*TRAIN_FLAGS, f"--dataset_dir={data}", "--num_steps=100"]
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert train.main([*flags, f"--workdir={whole}"]) == 0
    delay = np.random.default_rng(seed).uniform(0.0, 2.0)      # [s] after the first step is logged
    rc = _kill_when([sys.executable, "-m", "experiments.train", *flags, f"--workdir={cut}"],
                    lambda: (cut / "metrics.jsonl").exists() and (cut / "metrics.jsonl").stat().st_size > 0, delay)
    print(f"killed: rc={rc}, periodic steps {checkpoint.steps(cut / 'checkpoints' / 'periodic')}")
    assert train.main([*flags, f"--workdir={cut}", "--resume"]) == 0
    a = checkpoint.load(whole, make_synthetic_trajectory(1.0), which="periodic")
    b = checkpoint.load(cut, make_synthetic_trajectory(1.0), which="periodic")
    for x, y in zip(jax.tree.leaves(a.params), jax.tree.leaves(b.params)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert _steps_logged(cut) == _steps_logged(whole)
