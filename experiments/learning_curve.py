"""Learning curves (issue 24): test errors of the MGN and the baselines against the number of solver runs.

  python -m experiments.learning_curve --point 8=runs/lc_n8/eval/metrics.json \
      24=runs/family/eval/metrics.json,runs/family_s1/eval/metrics.json 48=runs/lc_n48/eval/metrics.json \
      --out results/learning_curve

Each ``N=FILES`` after ``--point`` gives evaluate()'s metrics.json of the MGN runs trained on N solver
runs (one file per seed), all evaluated on the same test scenes; their baselines were fitted on the same
runs' training split. Writes OUT/learning_curve.{json,md,png} (pcmgn_jax/eval/learning_curve.py).
For more training scenes than one LHS holds: ``experiments.generate --pool`` (same test scenes).
"""
import json
import sys
from dataclasses import dataclass
from pathlib import Path

from pcmgn_jax import cli


@dataclass(frozen=True)
class CurveArgs:
    point: tuple[str, ...] = ()    # N=metrics.json[,metrics.json...] ..., space-separated after one --point
    out: str = "results/learning_curve"   # output folder


def main(argv=None) -> int:
    args = cli.parse(CurveArgs, argv, description=__doc__, prog="python -m experiments.learning_curve")
    from pcmgn_jax.atomic import atomic_write_text
    from pcmgn_jax.eval.learning_curve import crossings, curve_plot, curve_rows, curve_table
    files = cli.keyed_paths(args.point, "point")
    specs = cli.keyed_json_files(args.point, "point")
    bad = [n for n in specs if not n.isdigit()]
    if bad or not specs:
        raise ValueError(f"--point: give N=metrics.json[,...] with N a whole number of solver runs "
                         f"(got {bad or 'none'})")
    points = {int(n): files for n, files in specs.items()}
    paths = {int(n): [str(p) for p in fs] for n, fs in files.items()}
    rows = curve_rows(points)
    command = cli.command_line("experiments.learning_curve", argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    text = "\n".join([f"`{command}`", "", curve_table(rows)])
    atomic_write_text(out / "learning_curve.md", text + "\n")
    atomic_write_text(out / "learning_curve.json", json.dumps(
        {"command": command, "files": paths, "rows": rows,
         "crossings": crossings(rows)}, indent=1) + "\n")
    curve_plot(rows, out / "learning_curve.png")
    print(text)
    print(f"wrote {out}/learning_curve.{{md,json,png}}")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
