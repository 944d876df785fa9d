"""Evaluate a run on its test split, or on any directory of trajectory files.

  python -m experiments.evaluate --workdir RUN [--which best|periodic]
  python -m experiments.evaluate --workdir RUN --data data/cpu/extrap      # -> RUN/eval/extrap/metrics.json
  python -m experiments.evaluate --workdir RUN --contact_projection off --name raw   # the network's raw contact

Rolls the model out from frame 0 of each trajectory and scores it beside the baselines fitted on the
run's training split (nothing moves, nearest training design, per-node quadratic and RBF regression over
the design, kriging and MOP response surfaces, a POD reduced-order model: pcmgn_jax.eval.baselines). A baseline that
needs the training mesh says so (``not_applicable``) when the data's mesh differs. Writes RUN/eval[/NAME]/metrics.json
(same keys either way) and PNG plots. The run's splits come from its config's dataset directory by
pcmgn_jax.data.splits.load_splits, for a generated or an imported (manifest-less) dataset alike: test = the first n_test
of DIR/test. The pipeline is pcmgn_jax.eval.run (pcmgn_jax/eval/pipeline.py); this module parses flags and prints.
"""
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from pcmgn_jax import cli


@dataclass(frozen=True)
class EvaluateArgs:
    workdir: str                               # training run directory (config.json, checkpoints)
    which: Literal["best", "periodic"] = "best"  # checkpoint: best validation or latest periodic
    data: str = ""                             # directory of trajectory files ("" = the run's test split)
    name: str = ""                             # output RUN/eval/NAME ("" = the --data folder's name)
    # val: score the run's validation trajectories (RUN/eval/val): choose rollout settings there, not on test
    split: Literal["test", "val"] = "test"
    contact_projection: Literal["", "on", "off"] = ""  # override the run's rollout contact projection ("" = the run's)
    # a residual_of run: who moves the rigid ball in the rollouts ("" = the run's residual_ball)
    residual_ball: Literal["", "baseline", "network"] = ""
    # also roll out the training split: a GP of the MGN's objective residuals gives each prediction a ± (metrics.json
    # mgn_spread)
    mgn_spread: bool = False
    # fit and score the baselines beside the model (--no_baselines: the model only; runs of one recipe on one
    # dataset share the baselines, e.g. a compute curve's, experiments.compute_curve)
    baselines: bool = True


def main(argv=None) -> int:
    args = cli.parse(EvaluateArgs, argv, description=__doc__, prog="python -m experiments.evaluate")
    import matplotlib
    matplotlib.use("Agg")  # files only; set here, in the entry point, not in the library
    from pcmgn_jax.eval import run
    from pcmgn_jax.eval.evaluate import summary_table
    from pcmgn_jax.eval.pipeline import output_name
    m = run(args.workdir, which=args.which, data=args.data, name=args.name,
            contact_projection=args.contact_projection, mgn_spread=args.mgn_spread, residual_ball=args.residual_ball,
            split=args.split, baselines=args.baselines)
    print(summary_table(m))
    if "mgn_spread" in m:
        s = m["mgn_spread"]
        for n, f, sd, e in zip(s["names"], s["objective_mpa"], s["std_mpa"], s["error_pct"]):
            print(f"  {n}: MGN objective {f:.4g} ± {sd:.2g} MPa ({s['source']}); real error {e:.2f} %")
        rho = s["spearman_error"]["rho"]
        print(f"  Spearman ρ(±, error) = {'n/a (' + s['spearman_error']['why'] + ')' if rho is None else f'{rho:.2f}'}")
    print(f"wrote {Path(args.workdir) / 'eval' / (output_name(args.data, args.name) or '')}/metrics.json and PNGs")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
