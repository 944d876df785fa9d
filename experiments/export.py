"""Export ground truth, prediction and error of one trajectory to ParaView (XDMF).

  python -m experiments.export --trajectory data/paper/test/test_0003 --pred pred.npz --out out/cmp
  python -m experiments.export --workdir runs/cpu --trajectory data/cpu/test/test_0003   # trained model

``--pred FILE.npz`` holds ``displacement`` (T, N, 2) [m] (or ``positions`` (T, N, 2) [m]) and
``von_mises`` (T, N) [Pa]. Open the written .xdmf in ParaView and apply "Warp By Vector" with
displacement_true or displacement_pred.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pcmgn_jax import cli
from pcmgn_jax.data.trajectory_io import read_trajectory
from pcmgn_jax.eval.export import export_comparison


@dataclass(frozen=True)
class ExportArgs:
    trajectory: str                 # trajectory path stem (dir/NAME) of the ground truth
    workdir: str | None = None      # training run directory: predict with its model (best checkpoint)
    pred: str | None = None         # predicted arrays (.npz: displacement|positions, von_mises)
    out: str | None = None          # output path stem (default: WORKDIR/export/NAME or NAME_compare)


def predict_with_model(workdir: Path, truth):
    """(displacement (T,N,2) [m], von_mises (T,N) [Pa]) of the trained model in ``workdir``
    rolled out from frame 0 of ``truth`` (best checkpoint)."""
    from pcmgn_jax.surrogates.mgn import MGNSurrogate

    disp, vm = MGNSurrogate(workdir, truth).rollout_trajectories([truth])
    return disp[0], vm[0]


def main(argv: list[str] | None = None) -> int:
    try:
        args = cli.parse(ExportArgs, argv, description=__doc__, prog="python -m experiments.export")
        if not (args.pred or args.workdir):
            raise ValueError("give --workdir RUN (trained model) or --pred FILE.npz (predicted arrays)")
        truth = read_trajectory(args.trajectory)
        name = Path(args.trajectory).with_suffix("").name if Path(args.trajectory).suffix in (
            ".xdmf", ".json", ".h5") else Path(args.trajectory).name
        if args.pred:
            with np.load(args.pred, allow_pickle=False) as z:
                kind = "displacement" if "displacement" in z.files else "positions"
                if kind not in z.files or "von_mises" not in z.files:
                    raise ValueError(f"{args.pred}: needs arrays 'displacement' (or 'positions') and "
                                     f"'von_mises', has {z.files}")
                pred, vm = z[kind], z["von_mises"]
        else:
            kind = "displacement"
            pred, vm = predict_with_model(Path(args.workdir), truth)
        out = Path(args.out) if args.out else (
            Path(args.workdir) / "export" / name if args.workdir else Path(f"{name}_compare"))
        path = export_comparison(truth, pred, vm, out, pred_kind=kind)
    except (ValueError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
