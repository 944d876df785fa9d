"""The code record every metrics.json carries (pcmgn_jax/provenance.py)."""
import re
import subprocess

import pytest

from fixtures.helpers import ROOT
from pcmgn_jax.provenance import code_version


def test_outside_a_checkout_there_is_no_commit(tmp_path):
    rec = code_version(tmp_path)
    from importlib import metadata
    assert rec["commit"] is None and rec["dirty"] is None and rec["version"] == metadata.version("pcmgn_jax")


@pytest.mark.skipif(not (ROOT / ".git").exists(), reason="not a git checkout")
def test_a_checkout_records_its_commit_and_whether_it_is_dirty(tmp_path):
    rec = code_version(ROOT)
    assert re.fullmatch(r"[0-9a-f]{40}", rec["commit"]) and isinstance(rec["dirty"], bool)
    repo = tmp_path / "r"
    repo.mkdir()
    git = ["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run(git[:3] + ["init", "-q"], check=True)
    (repo / "f.txt").write_text("a")
    subprocess.run(git + ["add", "f.txt"], check=True)
    subprocess.run(git + ["commit", "-qm", "one"], check=True)
    clean = code_version(repo)
    assert clean["dirty"] is False and clean["commit"] == subprocess.run(
        git[:3] + ["rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    (repo / "f.txt").write_text("b")
    assert code_version(repo)["dirty"] is True
