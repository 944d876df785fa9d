"""Where a run's objective error comes from: its error budget on the test split.

  python -m experiments.error_budget --workdir RUN [--dataset_dir DATA] [--out DIR] [--which best|periodic]

Rolls the run's model out on its test split (as experiments.evaluate does), makes every frame once more one step
from the true previous frame (teacher-forced) and, for a quasi-static panel, reads the panel at the true ball path;
then splits the objective error by mode (map, one step, drift), impact phase, node group of the section (interior
vs the interfaces with the neighbouring layers), pulse (peak and width) and part. Writes
DIR/error_budget.{md,png,json} (default RUN/error_budget); the library is pcmgn_jax/eval/error_budget.py.
An analysis of an already trained run's test error: nothing is chosen on it.
"""
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from pcmgn_jax import cli


@dataclass(frozen=True)
class BudgetArgs:
    workdir: str                                  # training run directory (config.json, checkpoints)
    out: str = ""                                 # output folder ("" = RUN/error_budget)
    which: Literal["best", "periodic"] = "best"   # checkpoint: best validation or latest periodic
    dataset_dir: str = ""                         # the run's dataset, test split in DATA/test ("" = its config's)
    part: str = "OLED"                            # the part whose section mean is the objective


def main(argv=None) -> int:
    args = cli.parse(BudgetArgs, argv, description=__doc__, prog="python -m experiments.error_budget")
    import matplotlib
    matplotlib.use("Agg")  # files only; set here, in the entry point, not in the library
    import numpy as np

    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.data.splits import load_splits
    from pcmgn_jax.eval.error_budget import budget, predictions
    from pcmgn_jax.eval.error_budget_page import tables, write
    from pcmgn_jax.mgn.checkpoint import require_run
    require_run(args.workdir)
    cfg = TrainConfig.load(Path(args.workdir) / "config.json")
    test = load_splits(args.dataset_dir or cfg.resolved_dataset_dir, n_train=0, n_val=0, n_test=cfg.n_test)[2]
    b = budget(test, predictions(args.workdir, test, which=args.which), part_name=args.part)
    command = cli.command_line("experiments.error_budget", argv)
    b["command"] = command
    out = write(Path(args.out or Path(args.workdir) / "error_budget"), b, np.asarray(test[0].times) * 1e6,
                header=f"`{command}`")
    print(tables(b))
    print(f"wrote {out}/error_budget.{{md,png,json}}")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
