"""The package's dependency rules (pyproject.toml [tool.importlinter]) hold: import-linter must pass.

import-linter comes with the dev extra (pip install -e '.[dev]'); without it this test fails, never skips.
"""
import os
import re
import subprocess
import sys

from fixtures.helpers import ROOT


def test_import_contracts():
    env = dict(os.environ, NO_COLOR="1", TERM="dumb", PYTHONPATH=str(ROOT))
    run = subprocess.run(
        [sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command; "
                               "sys.exit(lint_imports_command(['--no-cache']))"],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    report = re.sub(r"\x1b\[[0-9;]*m", "", run.stdout + run.stderr)
    assert run.returncode == 0, f"import contracts broken (pyproject.toml [tool.importlinter]):\n{report}"
