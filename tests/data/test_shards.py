"""Sharded generation (experiments.generate --shard K/N, --merge): the same dataset as one process, parts
instead of a shared manifest, a merge that names what is missing. The fake solver in this process and in
two concurrent processes; the real solver in two concurrent processes (slow)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fixtures.helpers import ROOT, TESTS
from fixtures.synthetic import FakeSolver
from pcmgn_jax.data import dataset as ds, shards
from pcmgn_jax.data.trajectory_io import read_sidecar, read_trajectory
from pcmgn_jax.scene import default_scene

TIMINGS = ("wall_time_s",)
# scipy's Lanczos (eigsh, tol 1e-4, no start vector) for the stable step: ARPACK's start vector depends on
# how many eigsh calls the process made before, so these two estimates differ between processes at ~1e-8
ESTIMATES = ("omega2_mesh", "omega2_coupled")


@pytest.fixture
def fake(monkeypatch):
    """the fake solver (fixtures.synthetic.FakeSolver) in place of pcmgn_jax.sim.solver."""
    monkeypatch.setitem(sys.modules, "pcmgn_jax.sim.solver", solver := FakeSolver())
    return solver


def _drop_timings(obj, drop=TIMINGS):
    if isinstance(obj, dict):
        return {k: _drop_timings(v, drop) for k, v in obj.items() if k not in drop}
    if isinstance(obj, list):
        return [_drop_timings(v, drop) for v in obj]
    return obj


def _files(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())


def assert_same_dataset(a: Path, b: Path) -> None:
    """Same files, same arrays (content hash and values), same sidecars and manifest but for timings."""
    assert _files(a) == _files(b)
    assert _drop_timings(ds.load_manifest(a)) == _drop_timings(ds.load_manifest(b))
    for stem in [p.with_suffix("") for p in a.rglob("*.json") if p.name != "manifest.json"]:
        other = b / stem.relative_to(a)
        sa, sb = read_sidecar(stem), read_sidecar(other)
        assert _drop_timings(sa, TIMINGS + ESTIMATES) == _drop_timings(sb, TIMINGS + ESTIMATES), stem
        for key in ESTIMATES if isinstance(sa.get("solver"), dict) and ESTIMATES[0] in sa["solver"] else ():
            assert sa["solver"][key] == pytest.approx(sb["solver"][key], rel=1e-4), (stem, key)
        ta, tb = read_trajectory(stem), read_trajectory(other)
        for field in ("points", "cells", "displacement", "velocity", "von_mises"):
            np.testing.assert_array_equal(getattr(ta, field), getattr(tb, field))


def test_parse_shard():
    assert shards.parse_shard("0/1") == (0, 1) and shards.parse_shard(" 7 / 8 ") == (7, 8)
    for bad, msg in [("8/8", r"0\.\.7"), ("1/0", "N >= 1"), ("3", "expected K/N"), ("-1/4", "expected K/N"),
                     ("a/b", "expected K/N")]:
        with pytest.raises(ValueError, match=msg):
            shards.parse_shard(bad)
    # batches of 2 over 5 designs, 2 shards: batches 0 and 2 -> shard 0, batch 1 -> shard 1
    assert [shards.owner(i, batch=2, n=2) for i in range(5)] == [0, 0, 1, 1, 0]


def test_two_shards_equal_one_process(tmp_path, fake):
    kw = {"preset": "tiny", "n_train": 3, "n_test": 2, "seed": 0, "batch": 2, "progress": False}
    one, two = tmp_path / "one", tmp_path / "two"
    ds.ensure_dataset(one, **kw)
    fake.calls.clear()
    ds.ensure_dataset(two, shard=(1, 2), **kw)
    assert [len(c[1]) for c in fake.calls] == [2]                 # batch 1: train_0002, test_0000
    assert not (two / "manifest.json").exists()
    with pytest.raises(ds.DatasetError, match="not merged yet"):  # training refuses an unmerged directory
        ds.dataset_source(two)
    ds.ensure_dataset(two, shard=(0, 2), **kw)                    # rerun-safe: a shard in a shared directory
    assert [len(c[1]) for c in fake.calls] == [2, 2, 1]           # the unsharded run's batches
    parts = shards.read_parts(two)
    assert [p["shard"] for p in parts] == [[0, 2], [1, 2]] and all(p["complete"] for p in parts)
    assert [t["name"] for t in parts[1]["trajectories"]] == ["train_0002", "test_0000"]
    fake.calls.clear()
    ds.ensure_dataset(two, merge=True, **kw)
    assert fake.calls == [] and not (two / ".shards").exists()
    assert_same_dataset(one, two)
    assert ds.dataset_source(two) == ds.GENERATE


def test_merge_names_missing_and_failed_designs(tmp_path, fake, monkeypatch):
    kw = {"preset": "tiny", "n_train": 4, "n_test": 2, "seed": 0, "batch": 1, "progress": False}
    out = tmp_path / "d"
    with pytest.raises(ds.DatasetError, match=r"(?s)6 of 6 .*train_0000 .*no shard part records it"):
        ds.ensure_dataset(out, merge=True, **kw)
    ds.ensure_dataset(out, shard=(0, 3), **kw)                    # train_0000, train_0003
    fail = FakeSolver(fail_above=0)                                # every design fails in shard 2
    monkeypatch.setitem(sys.modules, "pcmgn_jax.sim.solver", fail)
    with pytest.raises(ds.DatasetError, match="2 design.*failed"):
        ds.ensure_dataset(out, shard=(2, 3), **kw)
    monkeypatch.setitem(sys.modules, "pcmgn_jax.sim.solver", fake)
    with pytest.raises(ds.DatasetError) as err:
        ds.ensure_dataset(out, merge=True, **kw)
    msg = str(err.value)
    assert "4 of 6 trajectories missing" in msg and "manifest.json not written" in msg
    assert "train_0001 design_um=" in msg and "shard 1/3 wrote no part" in msg
    assert "train_0002" in msg and "shard 2/3 failed in the solver: SolverError" in msg
    assert "train_0000" not in msg and not (out / "manifest.json").exists()
    # the shards of one sweep share N and --batch; another run's shards do not share the directory
    with pytest.raises(ds.DatasetError, match="same N and --batch"):
        ds.ensure_dataset(out, shard=(1, 4), **kw)
    with pytest.raises(ds.DatasetError, match="a shard of another run"):
        ds.ensure_dataset(out, shard=(1, 3), **{**kw, "seed": 1})
    ds.ensure_dataset(out, shard=(1, 3), **kw)
    ds.ensure_dataset(out, shard=(2, 3), **kw)
    (out / "train" / "train_0003.h5").write_bytes(b"junk")         # written by shard 0, then corrupted
    with pytest.raises(ds.DatasetError, match=r"train_0003 .*shard 0/3 recorded it, but the file .* does not verify"):
        ds.ensure_dataset(out, merge=True, **kw)
    # an unsharded run completes the directory itself and deletes the parts
    fake.calls.clear()
    ds.ensure_dataset(out, **kw)
    assert [len(c[1]) for c in fake.calls] == [1] and not (out / ".shards").exists()
    assert all(e["sha256"] for s in ("train", "test") for e in ds.load_manifest(out)["splits"][s]["trajectories"])


def test_cli_shard_and_merge(tmp_path, fake, capsys):
    from experiments.generate import main

    out = tmp_path / "cli"
    flags = ["--out", str(out), "--preset", "tiny", "--n_train", "1", "--n_val", "0", "--n_test", "1",
             "--batch", "1", "--no_progress"]
    assert main(flags + ["--shard", "2/2"]) == 2
    assert "K must be in 0..1" in capsys.readouterr().err
    assert main(flags + ["--shard", "0/2"]) == 0 and "merge with --merge" in capsys.readouterr().out
    assert main(flags + ["--merge"]) == 2
    assert "test_0000 design_um=" in capsys.readouterr().err
    assert main(flags + ["--shard", "1/2"]) == 0 and main(flags + ["--merge"]) == 0
    assert len(ds.split_stems(out, "test")) == 1


_SCENE_FRAMES = 4       # frames of the scene the solver test runs (the tiny mesh; compile time dominates)
# a child process that runs experiments.generate with the fake solver in place of the real one
_FAKE_CHILD = ("import sys; from fixtures.synthetic import FakeSolver; "
               "sys.modules['pcmgn_jax.sim.solver'] = FakeSolver(); "
               "from experiments.generate import main; sys.exit(main(sys.argv[1:]))")


def _args(out: Path, scene: Path, *extra: str) -> list[str]:
    return ["--preset", "tiny", "--scene", str(scene), "--n_train", "2", "--n_val", "0", "--n_test", "1",
            "--batch", "1", "--no_progress", "--out", str(out), *extra]


def _generate(args: list[str], env: dict, use_fake: bool) -> subprocess.Popen:
    run = ["-c", _FAKE_CHILD] if use_fake else ["-m", "experiments.generate"]
    return subprocess.Popen([sys.executable, *run, *args], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def _wait(proc: subprocess.Popen) -> None:
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, out


@pytest.mark.parametrize("solver", ["fake", pytest.param("solver", marks=pytest.mark.slow)])  # solver: ~35 s
def test_concurrent_shard_processes_equal_one_process(tmp_path, solver, monkeypatch):
    """Two `generate --shard` processes at once into one directory, then --merge: the same files, arrays
    and manifest (but for timings) as one unsharded process; with the fake solver (the unsharded run and
    the merge in this process) and with the real one (every run a process of its own)."""
    import dataclasses

    from experiments import generate

    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(dataclasses.replace(default_scene(), n_frames=_SCENE_FRAMES).to_dict()))
    env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "xla_cache"),
           "PYTHONPATH": os.pathsep.join([str(ROOT), str(TESTS), os.environ.get("PYTHONPATH", "")])}
    use_fake = solver == "fake"
    if use_fake:
        monkeypatch.setitem(sys.modules, "pcmgn_jax.sim.solver", FakeSolver())

    def run(args):
        if use_fake:
            assert generate.main(args) == 0
        else:
            _wait(_generate(args, env, use_fake))

    t0 = time.perf_counter()
    run(_args(tmp_path / "one", scene))                           # (real solver: fills the compilation cache)
    procs = [_generate(_args(tmp_path / "two", scene, "--shard", f"{k}/2"), env, use_fake) for k in (0, 1)]
    for p in procs:
        _wait(p)
    run(_args(tmp_path / "two", scene, "--merge"))
    print(f"generate, two shards at once, merge: {time.perf_counter() - t0:.1f} s")
    assert_same_dataset(tmp_path / "one", tmp_path / "two")
    solver_meta = read_sidecar(tmp_path / "two" / "train" / "train_0001")["solver"]
    assert solver_meta["batch_um" if use_fake else "batch_size"] is not None    # the records that tell batches apart
