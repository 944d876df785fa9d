"""Write one self-contained HTML report of a run: metrics beside the baselines, plots, config, data provenance.

  python -m experiments.report --workdir runs/cpu                  # -> runs/cpu/report.html
  python -m experiments.report --workdir runs/cpu --name extrap --out extrap.html   # RUN/eval/extrap instead

Needs RUN/eval[/NAME]/metrics.json (``python -m experiments.evaluate --workdir RUN``); the PNGs beside it are
embedded, so the file opens anywhere without the run directory. Optimise results under RUN/opt*/ get the
Table-8 table (pcmgn_jax/opt/table.py). The report: pcmgn_jax/eval/report.py; this module parses flags.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass

from pcmgn_jax import cli


@dataclass(frozen=True)
class ReportArgs:
    workdir: str             # run directory (eval/metrics.json, config.json, data.json, optimize/)
    out: str = ""            # the HTML file ("" = RUN/report.html, RUN/report_NAME.html with --name)
    name: str = ""           # report RUN/eval/NAME (an evaluate --data / --name folder) instead of RUN/eval


def main(argv=None) -> int:
    args = cli.parse(ReportArgs, argv, description=__doc__, prog="python -m experiments.report")
    from pcmgn_jax.eval.report import optimize_results, write_report
    from pcmgn_jax.opt.table import rows
    found = optimize_results(args.workdir)
    path = write_report(args.workdir, args.out or None, name=args.name, optimize_table=rows(found) if found else None)
    print(f"wrote {path} ({path.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
