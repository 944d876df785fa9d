"""Generate (or resume) a trajectory dataset with the built-in solver.

  python -m experiments.generate --n_train 100 --n_test 50 --out data/paper --preset paper --seed 0
  python -m experiments.generate --out data/paper --preset paper --designs "40,40;40,160;160,40;160,160" --split extrap

Designs are OCA thicknesses in µm on the command line, metres in files. Rerunning skips finished,
valid trajectories. See pcmgn_jax/data/dataset.py for the directory layout and manifest.
"""
from __future__ import annotations

import argparse
import sys

from pcmgn_jax.data.dataset import PRESETS, DatasetError, ensure_dataset, parse_designs
from pcmgn_jax.scene import Scene, default_scene


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="dataset directory")
    ap.add_argument("--preset", default="cpu", choices=PRESETS, help="mesh resolution / frame count")
    ap.add_argument("--n_train", type=int, default=100, help="LHS training designs")
    ap.add_argument("--n_test", type=int, default=50, help="LHS test designs")
    ap.add_argument("--seed", type=int, default=0, help="LHS seed")
    ap.add_argument("--low_um", type=float, default=50.0, help="LHS lower bound [µm]")
    ap.add_argument("--high_um", type=float, default=150.0, help="LHS upper bound [µm]")
    ap.add_argument("--designs", default=None, help='explicit designs in µm, e.g. "40,40;40,160"')
    ap.add_argument("--split", default=None, help="split name for --designs (default: extrap)")
    ap.add_argument("--scene", default=None, help="scene file (.toml/.json); default: the paper's scene")
    ap.add_argument("--batch", type=int, default=8, help="designs per solver call")
    ap.add_argument("--no_progress", action="store_true", help="disable the progress bar")
    args = ap.parse_args(argv)
    try:
        scene = Scene.load(args.scene) if args.scene else default_scene()
        designs = parse_designs(args.designs, dim=len(scene.design_layers)) if args.designs else None
        if args.split and designs is None:
            ap.error("--split needs --designs")
        out = ensure_dataset(args.out, preset=args.preset, n_train=args.n_train, n_test=args.n_test,
                             seed=args.seed, designs=designs, split=args.split, scene=scene,
                             batch=args.batch, progress=not args.no_progress,
                             low=args.low_um * 1e-6, high=args.high_um * 1e-6)
    except (DatasetError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"dataset ready: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
