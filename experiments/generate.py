"""Generate (or resume) a trajectory dataset with the built-in solver.

  python -m experiments.generate --preset cpu --out data/cpu          # the designs experiments.train uses
  python -m experiments.generate --n_train 100 --n_val 5 --n_test 50 --out data/paper --preset paper --seed 0
  python -m experiments.generate --out data/paper --preset paper --designs "40,40;40,160;160,40;160,160" --split extrap
  python -m experiments.generate --out data/family --preset family --split extrap \
      --scene_params "ball.radius=3.5e-3,ball.velocity=0.8,OCA1=40e-6,OCA2=160e-6,POL=25e-6"  # outside the family's box
  python -m experiments.generate --preset paper --out data/paper --shard 3/8     # one task of an array job
  python -m experiments.generate --preset paper --out data/paper --merge         # after all shards: the manifest
  python -m experiments.generate --out data/family48 --pool data/family,data/family_extra   # solve nothing: pool
  python -m experiments.generate --preset stack --out data/stack_e2 --stack_split e2   # stacks: 5 & 7 layers / 6

``--n_train`` counts training trajectories, validation excluded, as in ``experiments.train``: the train
split gets n_train + n_val designs (``experiments.train --dataset_dir OUT`` then trains on n_train and
validates on n_val of them without size flags).
Designs are OCA thicknesses in µm on the command line, metres in files. Rerunning skips finished,
valid trajectories. See pcmgn_jax/data/dataset.py for the directory layout and manifest.
``--shard K/N`` (K from 0, as SLURM_ARRAY_TASK_ID with --array=0-(N-1)) solves every N-th solver batch of
the same design list and writes a manifest part; ``--merge`` with the shards' other flags verifies every
trajectory and writes the manifest (pcmgn_jax/data/shards.py).
``--pool A,B,...`` solves nothing: it writes the train splits of the datasets A, B, ... (renumbered) and
the test split of A into OUT, a directory without a manifest (read as an imported dataset: validation is
the last n_val of train), e.g. 48 family training scenes from two LHS seeds with the same test scenes
(pcmgn_jax.data.splits.pool_datasets).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import ClassVar, Literal

from pcmgn_jax import cli
from pcmgn_jax.data.dataset import DatasetError, ensure_dataset
from pcmgn_jax.data.designs import DESIGN_HIGH, DESIGN_LOW, FAMILIES, parse_designs, parse_scene_params
from pcmgn_jax.data.shards import parse_shard
from pcmgn_jax.presets import PRESETS, PresetName
from pcmgn_jax.scene import Scene, default_scene


@dataclass(frozen=True)
class GenerateArgs:
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"n_train": (0, True), "n_val": (0, True), "n_test": (0, True), "low_um": (0, False),
                              "high_um": (0, False), "batch": (0, True)}
    out: str                                   # dataset directory
    # mesh resolution / frame count / scene family (pcmgn_jax.presets.PRESETS)
    preset: PresetName = "cpu"
    # training trajectories, validation excluded (as in experiments.train); None: the preset's (tiny 3, cpu 12,
    # paper 100)
    n_train: int | None = None
    # validation trajectories, written to the train split after the n_train; None: the preset's (tiny 1, cpu 2, paper 5)
    n_val: int | None = None
    n_test: int | None = None                  # LHS test designs; None: the preset's (tiny 2, cpu 6, paper 50)
    seed: int = 0                              # LHS seed
    low_um: float = DESIGN_LOW * 1e6           # LHS lower bound [µm]
    high_um: float = DESIGN_HIGH * 1e6         # LHS upper bound [µm]
    designs: str | None = None                 # explicit designs in µm, e.g. "40,40;40,160" (instead of LHS)
    # a scene family's explicit scenes,
    # SI: "ball.radius=3.5e-3,ball.velocity=0.8,OCA1=40e-6,OCA2=160e-6,POL=25e-6;..." (may leave its box)
    scene_params: str | None = None
    split: str | None = None                   # split name for --designs (None: extrap)
    scene: str | None = None                   # scene file (.toml/.json); default: the paper's scene
    batch: int = 0                             # designs per solver batch (0: 8 on CPU, 64 on an accelerator)
    progress: bool = True                      # progress bar (--no_progress: off)
    # K/N: only shard K (0-based, 0..N-1) of N; writes a manifest part, not the manifest
    shard: str | None = None
    # solve nothing: verify every trajectory of the shards, write the manifest
    merge: bool = False
    # A,B,...: solve nothing; pool A's and B's train splits and A's test split into OUT
    pool: str | None = None
    # stack presets: e1 train/test alike, e2 train 5 & 7 layers / test 6, e3 test balls of radius 6.5-7.5
    # mm (pcmgn_jax.data.stack.PLANS); None: OUT's manifest's plan, else e1
    stack_split: Literal["e1", "e2", "e3"] | None = None


def preset_sizes(preset: str) -> tuple[int, int, int]:
    """(n_train, n_val, n_test) of ``experiments.train --preset PRESET`` (the train split holds n_train + n_val)."""
    cfg = cli.TrainConfig.from_preset(preset)
    return cfg.n_train, cfg.n_val, cfg.n_test


def check_args(args: GenerateArgs, given: set[str]) -> None:
    """ValueError naming a design box upside down, or a flag that does not apply to the preset or mode
    (:func:`pcmgn_jax.cli.refuse_inapplicable`): before anything is created."""
    if args.shard is not None and args.merge:   # the library names the values; here, the flags
        raise ValueError("--shard and --merge exclude each other: run the shards, then --merge once")
    if not args.low_um < args.high_um:     # each > 0 and finite: BOUNDS (cli.check_bounds)
        raise ValueError(f"--low_um={args.low_um:g} and --high_um={args.high_um:g}: need 0 < low < high (µm)")
    family, explicit = args.preset in FAMILIES, args.designs is not None or args.scene_params is not None
    lhs = "explicit designs (--designs / --scene_params) are solved as given" if explicit else None
    pool = "--pool solves nothing: it only pools the datasets named" if args.pool is not None else None
    rules = {"stack_split": None if PRESETS[args.preset].family == "stack" else
             f"preset {args.preset!r} is no stack family (stack, stack_tiny)",
             **{k: lhs or (f"preset {args.preset!r} samples its family's ranges" if family else None)
                for k in ("low_um", "high_um")},
             **{k: lhs for k in ("n_train", "n_val", "n_test", "seed")}}
    if pool:
        rules = {k: pool for k in given - {"out", "pool", "progress", "help"}}
    cli.refuse_inapplicable(given, rules)


def main(argv: list[str] | None = None) -> int:
    try:
        args = cli.parse(GenerateArgs, argv, description=__doc__, prog="python -m experiments.generate")
        check_args(args, cli.given_flags(sys.argv[1:] if argv is None else argv))
        if args.pool is not None:
            from pcmgn_jax.data.splits import pool_datasets
            sources = [s for s in args.pool.split(",") if s]
            print(f"dataset ready: {pool_datasets(sources, args.out)} (pooled from {', '.join(sources)})")
            return 0
        scene = Scene.load(args.scene) if args.scene else default_scene()
        if args.designs and args.preset in FAMILIES:
            raise ValueError(f"--designs: preset {args.preset!r} is a scene family; give its scenes with "
                             f"--scene_params ({', '.join(FAMILIES[args.preset].names)}, SI)")
        designs = parse_designs(args.designs, dim=len(scene.design_layers)) if args.designs else None
        if args.scene_params is not None:
            if args.preset not in FAMILIES or designs is not None:
                raise ValueError(f"--scene_params needs a scene-family preset ({', '.join(FAMILIES)}) and no --designs")
            designs = parse_scene_params(args.scene_params, FAMILIES[args.preset].names,
                                         zero_ok=FAMILIES[args.preset].padded)
        if args.split and designs is None:
            raise ValueError("--split needs --designs or --scene_params")
        n_train, n_val, n_test = preset_sizes(args.preset)
        n_train = n_train if args.n_train is None else args.n_train
        n_val = n_val if args.n_val is None else args.n_val
        shard = parse_shard(args.shard) if args.shard is not None else None
        out = ensure_dataset(args.out, preset=args.preset, n_train=n_train + n_val,
                             n_test=n_test if args.n_test is None else args.n_test,
                             seed=args.seed, designs=designs, split=args.split, scene=scene,
                             batch=args.batch, progress=args.progress,
                             low=args.low_um * 1e-6, high=args.high_um * 1e-6, shard=shard, merge=args.merge,
                             stack_split=args.stack_split)
    except (DatasetError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if shard is not None:
        print(f"shard {shard[0]}/{shard[1]} done: {out} (merge with --merge once every shard is done)")
        return 0
    print(f"dataset ready: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
