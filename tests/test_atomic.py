"""pcmgn_jax.atomic: a failed write keeps the old file whole and leaves no temp file behind."""
import os

import pytest

from pcmgn_jax.atomic import atomic_write_text
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


def test_the_run_config_writes_atomically(tmp_path, monkeypatch):
    f = tmp_path / "config.json"
    TrainConfig().save_json(f)
    before = f.read_text()
    monkeypatch.setattr(os, "replace", lambda *a: (_ for _ in ()).throw(OSError("killed (simulated)")))
    with pytest.raises(OSError, match="simulated"):
        TrainConfig(num_steps=7).save_json(f)
    assert f.read_text() == before and TrainConfig.load(f) == TrainConfig()
