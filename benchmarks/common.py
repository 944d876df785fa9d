"""The benchmarks' shared command line and output (flags, result paths, JSON / Markdown); the library part
(machine facts, timing, the benchmark graph, the FLOP model) is :mod:`pcmgn_jax.eval.bench`."""
from __future__ import annotations

import json
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pcmgn_jax import cli, markdown
from pcmgn_jax.atomic import atomic_write_text

RESULTS = Path(__file__).resolve().parents[1] / "results" / "benchmarks"


# ---- command line: the experiments' (pcmgn_jax.cli: tyro dataclasses, --key=value, underscores) ---------

@dataclass(frozen=True, kw_only=True)
class Outputs:
    """The output flags every benchmark shares. A benchmark's flags: a frozen dataclass over this one, parsed by
    ``pcmgn_jax.cli.parse(Args, argv, description=__doc__, prog="python -m benchmarks.NAME")``."""

    json: str | None = None   # result JSON (default results/benchmarks/<benchmark>.json)
    md: str | None = None     # Markdown table (default: the JSON's path with .md)


def run(main: Callable[[Sequence[str] | None], object]) -> None:
    """``python -m benchmarks.NAME``: ``main(None)`` (flags from ``sys.argv``); a ``ValueError`` (an unknown flag,
    a bad value) is one ``error: ...`` line and exit status 2, as in the experiments (:func:`pcmgn_jax.cli.run`)."""
    def call(argv):
        out = main(argv)
        return out if isinstance(out, int) else 0
    sys.exit(cli.run(call))


# ---- output ----------------------------------------------------------------------------------

def default_paths(name: str, json_path: str | None, md_path: str | None) -> tuple[Path, Path]:
    j = Path(json_path) if json_path else RESULTS / f"{name}.json"
    m = Path(md_path) if md_path else j.with_suffix(".md")
    return j, m


def md_table(header: Sequence[str], rows: Sequence[Sequence]) -> str:
    """A benchmark's markdown table (pcmgn_jax.markdown.table), floats to 4 significant digits."""
    def fmt(v):
        return f"{v:.4g}" if isinstance(v, float) else v
    return "\n".join(markdown.table(header, ([fmt(v) for v in r] for r in rows))) + "\n"


def clean(obj):
    """JSON-safe: numpy scalars -> Python, non-finite floats -> None."""
    if isinstance(obj, Mapping):
        return {str(k): clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return clean(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if np.isfinite(f) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


def write_outputs(result: dict, json_path: Path, md_path: Path, markdown: str) -> None:
    """Write the result JSON (:func:`clean`) and the Markdown table, each atomically (pcmgn_jax.atomic)."""
    atomic_write_text(json_path, json.dumps(clean(result), indent=1, allow_nan=False) + "\n", parents=True)
    atomic_write_text(md_path, markdown, parents=True)
    print(markdown)
    print(f"wrote {json_path} and {md_path}")
