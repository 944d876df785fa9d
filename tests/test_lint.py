"""The code passes ruff (pyproject.toml [tool.ruff]: pyflakes, pycodestyle, import order, lines <= 120).

ruff comes with the dev extra (pip install -e '.[dev]'); without it this test skips, saying why.
Fix what it reports with ``ruff check --fix .`` (import order, unused imports) and by hand (long lines); the code is
formatted by hand, never with ``ruff format``.
"""
import shutil
import subprocess

import pytest

from fixtures.helpers import ROOT


def _ruff() -> str | None:
    """The ruff executable: the pip package's (``python -m ruff`` finds it the same way), else one on PATH."""
    try:
        from ruff.__main__ import find_ruff_bin
        return str(find_ruff_bin())
    except (ImportError, FileNotFoundError):
        return shutil.which("ruff")


def test_ruff_check_passes():
    ruff = _ruff()
    if ruff is None:
        pytest.skip("ruff is not installed (pip install -e '.[dev]')")
    run = subprocess.run([ruff, "check", "--no-cache", "--output-format", "concise", "."], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, f"ruff check . failed (pyproject.toml [tool.ruff]):\n{run.stdout}{run.stderr}"
