"""Which code made a result: recorded in every metrics.json so a table that mixes files from before and
after a change (e.g. the von Mises clamp of the rollout) can be told apart by their ``code`` record."""
from __future__ import annotations

import subprocess
from importlib import metadata
from pathlib import Path

_PACKAGE_ROOT = Path(__file__).resolve().parents[1]


def _git(root: Path, *args: str) -> str | None:
    try:
        run = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return None  # no git on this machine
    return run.stdout.strip() if run.returncode == 0 else None


def code_version(root: str | Path | None = None) -> dict:
    """{"version": the installed package version (None if not installed), "commit": the git commit of
    ``root`` (default this package's checkout; None outside a git checkout), "dirty": whether tracked
    files differ from that commit (None without a commit)}."""
    root = Path(root) if root is not None else _PACKAGE_ROOT
    try:
        version = metadata.version("pcmgn_jax")
    except metadata.PackageNotFoundError:
        version = None
    commit = _git(root, "rev-parse", "HEAD")
    dirty = None
    if commit is not None:
        status = _git(root, "status", "--porcelain", "--untracked-files=no")
        dirty = None if status is None else bool(status)
    return {"version": version, "commit": commit, "dirty": dirty}
