"""The documentation inside the repository: links resolve, code citations of docs/design.md point to its
sections, the README stays a front page and its test command is the one CI runs."""
from __future__ import annotations

import re

import pytest

from fixtures.helpers import ROOT

DOCS = sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]
LINK = re.compile(r"\]\(([^)\s]+)\)")


@pytest.mark.parametrize("page", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page):
    missing = []
    for target in LINK.findall(page.read_text(encoding="utf-8")):
        if re.match(r"^[a-z]+:", target) or target.startswith("#"):
            continue
        path = (page.parent / target.split("#", 1)[0]).resolve()
        if not path.exists():
            missing.append(target)
    assert not missing, f"{page.relative_to(ROOT)}: links to missing files {missing}"


def test_design_citations_name_existing_sections():
    design = (ROOT / "docs" / "design.md").read_text(encoding="utf-8")
    sections = set(re.findall(r"^#{2,3} (\d+(?:\.\d+)?)\.? ", design, flags=re.M))
    assert {"2", "3", "4", "5", "6", "8"} <= sections
    bad = []
    for folder in ("pcmgn_jax", "experiments", "benchmarks", "tests"):
        for f in (ROOT / folder).rglob("*"):
            if f.suffix not in (".py", ".toml", ".md") or not f.is_file():
                continue
            text = f.read_text(encoding="utf-8")
            if f.name == "test_docs.py":
                continue
            assert "DESIGN §" not in text and "DESIGN.md" not in text, f"{f}: cites a document not in the repository"
            bad += [(str(f.relative_to(ROOT)), n) for n in re.findall(r"docs/design\.md §(\d+(?:\.\d+)?)", text)
                    if n not in sections]
    assert not bad, f"citations of missing docs/design.md sections: {bad}"


def test_readme_is_a_front_page_with_ci_test_command():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.encode()) <= 20_000
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    command = 'python -m pytest -q -m "not slow" --durations=15'
    assert command in readme and command in ci


def test_docs_site_builds_strict(tmp_path):
    """mkdocs.yml over docs/ (material theme): `mkdocs build --strict` fails on any warning (a link that
    leaves docs/, a page missing from the nav's files, a broken anchor)."""
    pytest.importorskip("mkdocs", reason="mkdocs is not installed (pip install -e '.[docs]')")
    pytest.importorskip("material", reason="mkdocs-material is not installed (pip install -e '.[docs]')")
    import os
    import subprocess
    import sys
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                         cwd=ROOT, capture_output=True, text=True, timeout=120,
                         env=dict(os.environ, NO_MKDOCS_2_WARNING="1", NO_COLOR="1"))
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{run.stdout}\n{run.stderr}"
    assert (tmp_path / "site" / "index.html").exists() and (tmp_path / "site" / "design" / "index.html").exists()
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    missing = [p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*.md")
               if p.relative_to(ROOT / "docs").as_posix() not in nav]
    assert not missing, f"docs pages missing from the mkdocs.yml nav: {missing}"
