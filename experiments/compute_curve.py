"""The MGN's compute curve: test errors against training steps, a power-law fit, and where it meets the baselines.

  python -m experiments.compute_curve --runs "runs/cc/s*_seed*" --out results/compute_curve/a [--gpu_steps_per_s R]
      [--kept 16000:0:results/compute_curve/b/s16000_seed0_metrics.json,...]

Each run is one ``experiments.train`` run of the same recipe and dataset at its own ``--num_steps`` (the learning
rate's decay spread over its length) and seed, evaluated with ``experiments.evaluate`` (RUN/eval/metrics.json).
Fits error = a * steps^-b per metric (objective, position, stress), and states the steps at which the fit meets
each baseline of the same test split (kriging, MOP, the POD ROM, nearest design, no motion), with the 16–84 %
interval of fits drawn from the fit's covariance (and, for the objective, of test designs resampled), in hours at
the runs' median logged CPU rate and, with ``--gpu_steps_per_s``, at a GPU rate measured elsewhere (say where).
A run whose folder is gone enters by its kept evaluation (``--kept``, steps and seed given; no training rate).
Writes OUT/compute_curve.{json,md,png}; the library is pcmgn_jax/eval/compute_curve.py.
"""
import sys
from dataclasses import dataclass
from glob import glob
from pathlib import Path

from pcmgn_jax import cli


@dataclass(frozen=True)
class CurveArgs:
    runs: str                                 # comma-separated run directories or globs (each trained + evaluated)
    out: str                                  # output folder
    gpu_steps_per_s: float = 0.0              # a measured GPU training rate of the same recipe (0 = none)
    kept: str = ""                            # comma-separated STEPS:SEED:PATH: a gone run's eval/metrics.json


def main(argv=None) -> int:
    args = cli.parse(CurveArgs, argv, description=__doc__, prog="python -m experiments.compute_curve")
    import matplotlib
    matplotlib.use("Agg")  # files only; set here, in the entry point, not in the library

    from pcmgn_jax.atomic import atomic_write_json, atomic_write_text
    from pcmgn_jax.eval.compute_curve import curve_point, kept_point, markdown_lines, plot, summary
    runs = sorted({r for pat in args.runs.split(",") if pat.strip() for r in (glob(pat.strip()) or [pat.strip()])})
    kept = [kept_point(k) for k in args.kept.split(",") if k.strip()]
    if not runs and not kept:
        raise ValueError(f"--runs {args.runs!r}: no run directories")
    s = summary([curve_point(r) for r in runs] + kept, gpu_steps_per_s=args.gpu_steps_per_s or None)
    s["command"] = cli.command_line("experiments.compute_curve", argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "compute_curve.json", s)
    text = "\n".join([f"`{s['command']}`", "", *markdown_lines(s)]) + "\n"
    atomic_write_text(out / "compute_curve.md", text)
    plot(out / "compute_curve.png", s)
    print(text)
    print(f"wrote {out}/compute_curve.{{json,md,png}}")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
