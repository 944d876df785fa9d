"""Export ground truth, prediction and error of one trajectory to ParaView (XDMF).

  python -m experiments.export --trajectory data/paper/test/test_0003 --pred pred.npz --out out/cmp
  python -m experiments.export --workdir runs/cpu --trajectory data/cpu/test/test_0003   # trained model

``--pred FILE.npz`` holds ``displacement`` (T, N, 2) [m] (or ``positions`` (T, N, 2) [m]) and
``von_mises`` (T, N) [Pa]. Open the written .xdmf in ParaView and apply "Warp By Vector" with
displacement_true or displacement_pred.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from pcmgn_jax.data.export import export_comparison
from pcmgn_jax.data.trajectory_io import read_trajectory


def predict_with_model(workdir: Path, truth):
    """(displacement (T,N,2) [m], von_mises (T,N) [Pa]) of the trained model in ``workdir``
    rolled out from frame 0 of ``truth`` (best checkpoint)."""
    from pcmgn_jax.eval.evaluate import predict_trajectories

    disp, vm, _, _ = predict_trajectories(workdir, [truth])
    return disp[0], vm[0]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trajectory", required=True, help="trajectory path stem (dir/NAME) of the ground truth")
    ap.add_argument("--workdir", default=None, help="training run directory: predict with its model")
    ap.add_argument("--pred", default=None, help="predicted arrays (.npz: displacement|positions, von_mises)")
    ap.add_argument("--out", default=None, help="output path stem (default: WORKDIR/export/NAME or NAME_compare)")
    args = ap.parse_args(argv)
    try:
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
        elif args.workdir:
            kind = "displacement"
            pred, vm = predict_with_model(Path(args.workdir), truth)
        else:
            ap.error("give --workdir RUN (trained model) or --pred FILE.npz (predicted arrays)")
        out = Path(args.out) if args.out else (
            Path(args.workdir) / "export" / name if args.workdir else Path(f"{name}_compare"))
        path = export_comparison(truth, pred, vm, out, pred_kind=kind)
    except (ValueError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
