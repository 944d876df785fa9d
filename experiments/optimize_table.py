"""The design-optimisation results as one table like the paper's Table 8, a row per result JSON of
``experiments.optimize``, best solver-checked optimum first, beside the best of the dataset's own
solver-evaluated designs; each row's command is listed under the table.

  python -m experiments.optimize_table --files 'results/optimize/*.json,results/optimize/first_training/*.json' \
      --out results/optimize/table.md

A row names its file relative to the folder all the files share, so results of two models in two folders
(the same file names) stay apart; a surrogate's fingerprint (its parameters' hash) follows its name.
The table: pcmgn_jax/opt/table.py; this module expands the globs and writes it.
"""
from __future__ import annotations

import glob
import sys
from dataclasses import dataclass

from pcmgn_jax import cli
from pcmgn_jax.opt.table import rows


@dataclass(frozen=True)
class TableArgs:
    files: str = "results/optimize/*.json"      # comma-separated paths or globs (quote them) of optimize JSONs
    out: str = ""                               # write the table here (markdown) as well as printing it


def main(argv=None) -> int:
    args = cli.parse(TableArgs, argv, description=__doc__, prog="python -m experiments.optimize_table")
    paths = []
    for item in (s.strip() for s in args.files.split(",") if s.strip()):
        paths += sorted(glob.glob(item)) if any(c in item for c in "*?[") else [item]
    lines = rows(paths)
    if args.out:
        from pcmgn_jax.atomic import atomic_write_text
        atomic_write_text(args.out, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
