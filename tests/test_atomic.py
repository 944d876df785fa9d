"""pcmgn_jax.atomic: a failed write keeps the old file (or folder) whole and leaves no temp file behind."""
import json
import os

import numpy as np
import pytest

from pcmgn_jax.atomic import atomic_dir, atomic_write_json, atomic_write_text
from pcmgn_jax.config import TrainConfig


def test_a_failed_write_keeps_the_old_file_and_no_temp(tmp_path, monkeypatch):
    f = tmp_path / "table.md"
    atomic_write_text(f, "old\n")
    assert f.read_text() == "old\n" and oct(f.stat().st_mode & 0o777) == "0o644"

    def boom(src, dst):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="simulated"):
        atomic_write_text(f, "new\n")
    assert f.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["table.md"]


def test_json_in_the_projects_encoding_and_missing_folders_on_request(tmp_path):
    f = tmp_path / "a" / "b" / "out.json"
    with pytest.raises(FileNotFoundError):
        atomic_write_json(f, {})
    atomic_write_json(f, {"x": np.float32(1.5), "v": np.arange(2), "t": (1, 2), "nan": float("nan")}, parents=True)
    assert json.loads(f.read_text()) == {"x": 1.5, "v": [0, 1], "t": [1, 2], "nan": None}
    with pytest.raises(ValueError, match="not JSON-serialisable"):
        atomic_write_json(f, {"bad": object()})


def test_the_run_config_writes_atomically(tmp_path, monkeypatch):
    f = tmp_path / "config.json"
    TrainConfig().save_json(f)
    before = f.read_text()
    monkeypatch.setattr(os, "replace", lambda *a: (_ for _ in ()).throw(OSError("killed (simulated)")))
    with pytest.raises(OSError, match="simulated"):
        TrainConfig.of(num_steps=7).save_json(f)
    assert f.read_text() == before and TrainConfig.load(f) == TrainConfig()


def _tree(root):
    return {str(p.relative_to(root)): p.read_text() for p in sorted(root.rglob("*")) if p.is_file()}


def test_atomic_dir_replaces_the_folder_on_success(tmp_path):
    out = tmp_path / "run"
    with atomic_dir(out) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".run.tmp-")
        (tmp / "a.txt").write_text("1")
    with atomic_dir(out) as tmp:
        (tmp / "sub").mkdir()
        (tmp / "sub" / "b.txt").write_text("2")
    assert _tree(out) == {"sub/b.txt": "2"}            # the old folder's files are gone
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_atomic_dir_failure_inside_keeps_the_old_folder_and_no_temp(tmp_path):
    out = tmp_path / "run"
    with atomic_dir(out) as tmp:
        (tmp / "a.txt").write_text("old")
    with pytest.raises(RuntimeError, match="simulated"), atomic_dir(out) as tmp:
        (tmp / "a.txt").write_text("new")
        raise RuntimeError("simulated failure")
    assert _tree(out) == {"a.txt": "old"}
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_atomic_dir_failed_swap_puts_the_old_folder_back(tmp_path, monkeypatch):
    out = tmp_path / "run"
    with atomic_dir(out) as tmp:
        (tmp / "a.txt").write_text("old")
    real = os.replace

    def boom(src, dst):
        if str(dst) == str(out) and ".tmp-" in str(src):
            raise OSError("disk full (simulated)")
        real(src, dst)

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="simulated"), atomic_dir(out) as tmp:
        (tmp / "a.txt").write_text("new")
    assert _tree(out) == {"a.txt": "old"}
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_atomic_dir_refuses_a_file_in_the_way(tmp_path):
    (tmp_path / "run").write_text("x")
    with pytest.raises(NotADirectoryError), atomic_dir(tmp_path / "run"):
        pass
    assert (tmp_path / "run").read_text() == "x" and len(list(tmp_path.iterdir())) == 1


def test_atomic_dir_files_are_moved_into_a_shared_folder_marker_last(tmp_path, monkeypatch):
    (tmp_path / "other.txt").write_text("keep")
    names = ("a.h5", "a.xdmf", "a.json")
    with atomic_dir(tmp_path, files=names) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".a.tmp-")
        for n in names:
            (tmp / n).write_text("v1")
    assert _tree(tmp_path) == {"other.txt": "keep", **{n: "v1" for n in names}}
    moved = []
    real = os.replace

    def dying(src, dst):                  # killed after the first file is in: the old marker is gone
        moved.append(os.path.basename(dst))
        if len(moved) == 2:
            raise KeyboardInterrupt("killed (simulated)")
        real(src, dst)

    monkeypatch.setattr(os, "replace", dying)
    with pytest.raises(KeyboardInterrupt), atomic_dir(tmp_path, files=names) as tmp:
        for n in names:
            (tmp / n).write_text("v2")
    assert moved == ["a.h5", "a.xdmf"]
    assert _tree(tmp_path) == {"other.txt": "keep", "a.h5": "v2", "a.xdmf": "v1"}   # no marker: not valid
    monkeypatch.setattr(os, "replace", real)
    with pytest.raises(RuntimeError), atomic_dir(tmp_path, files=names) as tmp:
        raise RuntimeError("nothing written")
    assert not any(".tmp-" in p.name for p in tmp_path.iterdir())
