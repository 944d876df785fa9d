"""Time from nothing to the trainer's first batch: load a split from the packed cache and gather batch 1.

python -m benchmarks.cache_load --dataset data/cpu --split train --json results/benchmarks/cache_load.json
(issue 3's target: < 2 s for the default training split.) Builds the cache first if it is missing or stale,
outside the timing, and reports that build time separately.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass

import numpy as np

from benchmarks import common
from pcmgn_jax import cli
from pcmgn_jax.atomic import atomic_write_json
from pcmgn_jax.data.cache import ensure_cache, load_split
from pcmgn_jax.mgn.formulation import FORMULATIONS
from pcmgn_jax.train.sampling import gather, pair_table, sample_ids


@dataclass(frozen=True)
class CacheLoadArgs:
    dataset: str = "data/cpu"    # dataset directory
    split: str = "train"         # its split to load
    json: str | None = None      # result JSON (default: printed only)


def main(argv=None) -> int:
    args = cli.parse(CacheLoadArgs, argv, description=__doc__, prog="python -m benchmarks.cache_load")
    t0 = time.perf_counter()
    _, rebuilt = ensure_cache(args.dataset, args.split)
    build_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    trajs = load_split(args.dataset, args.split)
    t_load = time.perf_counter() - t0
    dt = float(trajs[0].times[1] - trajs[0].times[0])
    ids = sample_ids(0, 0, 1, 1, len(pair_table(trajs)))
    batch = gather(FORMULATIONS["default"], trajs, pair_table(trajs), ids, dt=dt)
    t_first = time.perf_counter() - t0
    out = {"dataset": args.dataset, "split": args.split, "trajectories": len(trajs),
           "nodes": trajs[0].n_nodes, "frames": trajs[0].n_frames,
           "cache_rebuilt": bool(rebuilt), "cache_build_s": build_s if rebuilt else 0.0,
           "cache_check_s": 0.0 if rebuilt else build_s,
           "load_split_s": t_load, "load_and_first_batch_s": t_first,
           "check_load_and_first_batch_s": t_first + (0.0 if rebuilt else build_s),
           "first_batch_shapes": {k: list(np.shape(v)) for k, v in batch.items()}}
    if args.json:
        atomic_write_json(args.json, out)
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    common.run(main)
