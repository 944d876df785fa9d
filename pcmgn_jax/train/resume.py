"""Where a killed training run resumes, and the files made consistent with it before it does.

:func:`resume_point` (called by :func:`pcmgn_jax.train.loop.train` with ``resume=True``, before its
checkpoint managers open): the newest periodic checkpoint that reads back whole (a damaged one is named and
set aside, :func:`pcmgn_jax.mgn.checkpoint.latest_intact`); the best and periodic checkpoints written after
it are removed (the resumed run writes them again, the same: the data order is a function of the step);
``metrics.jsonl`` is cut back to it (:func:`cut_metrics`), so no step is logged twice.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from pcmgn_jax.atomic import atomic_write_text
from pcmgn_jax.mgn import checkpoint

__all__ = ["cut_metrics", "resume_point"]


def resume_point(workdir: str | Path, *, write: bool = True) -> int | None:
    """The step ``workdir``'s run resumes from (None: no readable periodic checkpoint, a fresh start), with
    the checkpoints after it removed and ``metrics.jsonl`` cut back to it (see the module docstring).
    ``write=False`` (several hosts: every process but 0) only finds the step and changes no file."""
    root = Path(workdir) / "checkpoints"
    step = checkpoint.latest_intact(root / "periodic", set_aside=write)
    if not write:
        return step
    at = -1 if step is None else step
    for which in ("periodic", "best"):
        checkpoint.drop_after(root / which, at)
    cut_metrics(Path(workdir) / "metrics.jsonl", at)
    return step


def cut_metrics(path: Path, step: int) -> int:
    """Keep the lines of the JSON-lines log ``path`` whose ``step`` is <= ``step`` (atomic rewrite); a line
    that does not parse (a write cut by a kill) is dropped too. Returns the number of lines removed."""
    if not path.exists():
        return 0
    lines = path.read_text().splitlines()
    keep = []
    for line in lines:
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(rec, dict) and isinstance(rec.get("step"), int) and rec["step"] <= step:
            keep.append(line)
    dropped = len(lines) - len(keep)
    if dropped:
        atomic_write_text(path, "".join(k + "\n" for k in keep))
        print(f"note: {path}: {dropped} line(s) after step {max(step, 0)} removed (the run resumes there)",
              file=sys.stderr)
    return dropped
