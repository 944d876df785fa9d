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


def test_module_constants_have_one_meaning():
    """No two library modules define a public module-level constant of one name (issue 51: one name, one
    meaning; the same name twice is a second meaning or a second home)."""
    import ast
    from collections import defaultdict

    homes = defaultdict(list)
    for path in sorted((ROOT / "pcmgn_jax").rglob("*.py")):
        for node in ast.parse(path.read_text()).body:
            targets = (node.targets if isinstance(node, ast.Assign)
                       else [node.target] if isinstance(node, ast.AnnAssign) else [])
            for t in targets:
                if isinstance(t, ast.Name) and t.id.isupper() and not t.id.startswith("_"):
                    homes[t.id].append(str(path.relative_to(ROOT)))
    twice = {name: where for name, where in homes.items() if len(set(where)) > 1}
    assert not twice, f"constants defined in more than one module: {twice}"


def test_the_library_speaks_of_no_tracker_issue():
    """No ``issue N`` in library code (the docs say which issue a module serves); another project's issue,
    cited as its repository's (``CalculiX issue 63``), is a reference, not the tracker."""
    import re

    pattern = re.compile(r"(?<!CalculiX )\bissues? \d+", re.IGNORECASE)
    found = [f"{p.relative_to(ROOT)}:{n}" for p in sorted((ROOT / "pcmgn_jax").rglob("*.py"))
             for n, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert not found, f"tracker issue numbers in the library: {found}"
