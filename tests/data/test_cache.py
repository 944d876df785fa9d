"""Packed memory-mapped split cache: exact content, memmap views, rebuild only on hash change."""
from __future__ import annotations

import time

import numpy as np

from fixtures.synthetic import assert_same, synthetic_trajectory
from pcmgn_jax.data import cache
from pcmgn_jax.data.layout import split_stems
from pcmgn_jax.data.trajectory_io import read_trajectory, write_trajectory


def _make(root, n=3, dtype=np.float64):
    for i in range(n):
        write_trajectory(synthetic_trajectory(seed=i, dtype=dtype, n_frames=3 + i), root / "train" / f"t{i}")


def test_load_split_exact_and_memmapped(tmp_path):
    _make(tmp_path)
    trajs = cache.load_split(tmp_path, "train")
    assert [t.meta["name"] for t in trajs] == ["t0", "t1", "t2"]
    for stem, t in zip(split_stems(tmp_path, "train"), trajs):
        assert_same(read_trajectory(stem), t)
        assert isinstance(t.displacement.base, np.memmap) or isinstance(t.displacement, np.memmap)
        assert not t.displacement.flags.writeable
        t.validate()
    assert (tmp_path / ".cache" / "train" / "index.json").exists()


def test_rebuild_only_on_change(tmp_path):
    _make(tmp_path)
    _, rebuilt = cache.ensure_cache(tmp_path, "train")
    assert rebuilt
    _, rebuilt = cache.ensure_cache(tmp_path, "train")
    assert not rebuilt
    t0 = time.perf_counter()
    trajs = cache.load_split(tmp_path, "train")
    assert time.perf_counter() - t0 < 0.5
    new = synthetic_trajectory(seed=99, n_frames=4)
    write_trajectory(new, tmp_path / "train" / "t1")
    trajs_old = trajs
    path, rebuilt = cache.ensure_cache(tmp_path, "train")
    assert rebuilt
    trajs = cache.load_split(tmp_path, "train")
    assert_same(new, trajs[1])
    np.asarray(trajs_old[1].von_mises).sum()       # old memmaps stay readable after the swap
    # a new trajectory in the split also triggers a rebuild
    write_trajectory(synthetic_trajectory(seed=5), tmp_path / "train" / "t9")
    assert len(cache.load_split(tmp_path, "train")) == 4
    assert sorted(p.name for p in (tmp_path / ".cache").iterdir() if not p.name.startswith(".lock")) == ["train"]


def test_mixed_dtypes_promoted(tmp_path):
    write_trajectory(synthetic_trajectory(seed=0, dtype=np.float32), tmp_path / "s" / "a")
    write_trajectory(synthetic_trajectory(seed=1), tmp_path / "s" / "b")
    a, b = cache.load_split(tmp_path, "s")
    assert a.displacement.dtype == np.float64
    np.testing.assert_array_equal(a.displacement, synthetic_trajectory(seed=0, dtype=np.float32).displacement)
