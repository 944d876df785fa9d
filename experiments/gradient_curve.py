"""Gradient-enhanced kriging against plain kriging and the nearest design: objective error against solver cost.

  python -m experiments.gradient --dataset_dir DATA --split train --n 25 --out GRADS.json      # the gradients
  python -m experiments.gradient_curve --dataset_dir DATA --gradients GRADS.json --sizes 6,12,25,50,100 \
      --n_test 20 --out results/gradient_curve/b

Each kind is fitted on the first n training designs of DATA and scored on its first ``--n_test`` test designs
(the evaluation's objective error); gek at the sizes the gradient file covers, its cost n × the gradient's
measured cost in solves (pcmgn_jax/eval/gradient_curve.py). Writes gradient_curve.{json,md,png} to ``--out``.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass

from pcmgn_jax import cli


@dataclass(frozen=True)
class GradientCurveArgs:
    dataset_dir: str = ""               # a generated dataset (experiments.generate)
    gradients: str = ""                 # its design gradients (experiments.gradient --dataset_dir)
    sizes: str = "6,12,25,50,100"       # training-set sizes, comma-separated
    n_test: int = 20                    # the dataset's first n_test test designs
    out: str = "results/gradient_curve"  # folder of gradient_curve.{json,md,png}


def main(argv=None) -> int:
    args = cli.parse(GradientCurveArgs, argv, description=__doc__, prog="python -m experiments.gradient_curve")
    from pcmgn_jax.data.gradients import load_gradients
    from pcmgn_jax.errors import SettingError
    from pcmgn_jax.eval.gradient_curve import gradient_curve, write_gradient_curve

    for name in ("dataset_dir", "gradients"):
        if not getattr(args, name):
            raise SettingError(name, "is required")
    try:
        sizes = sorted({int(s) for s in args.sizes.split(",") if s.strip()})
    except ValueError:
        raise SettingError("sizes", f"{args.sizes!r}: give whole numbers, comma-separated") from None
    if not sizes or sizes[0] < 2:
        raise SettingError("sizes", f"{args.sizes!r}: every size must be >= 2")
    res = gradient_curve(args.dataset_dir, load_gradients(args.gradients), sizes=sizes, n_test=args.n_test)
    command = "python -m experiments.gradient_curve " + " ".join(sys.argv[1:] if argv is None else argv)
    print(f"wrote {write_gradient_curve(res, args.out, command)}")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
