"""Response time of the explorer per slider move (issue 27; goal <= 1 s with the run's default surrogate).

    python -m benchmarks.explore_latency --workdir runs/cpu [--moves 10] [--no_mgn] [--json PATH] [--md PATH]

The page's work for one move, warm (the run loaded, baselines fitted, the MGN compiled, two untimed moves
first), over ``--moves`` new designs spread over the sliders' range (seeded, none repeated, so nothing is
served from the cache):

- ``page``: ``Explorer.ask`` (the predictors fast enough to run at once, ``Explorer.live``) +
  ``Explorer.view`` (headline, table, figures) + the JSON of the figures: what the page shows at once;
- ``default``: until the run's default predictor is on the page: ``page``, plus, when the default is too
  slow to run at once (``Explorer.deferred``, e.g. the MGN on the cpu preset), ``Explorer.predict_rest``
  and a second ``view`` (the page's second update);
- ``kriging``: the same ``page`` work for an explorer of the run with kriging alone (no MGN, no other
  baseline): the objective with its GP std and the kriging fields.

Browser rendering is not included (the browser test prints the round trip it sees). Median and max [s].
"""
from __future__ import annotations

import json
import statistics
import time
from dataclasses import dataclass

import numpy as np

from benchmarks import common
from pcmgn_jax import cli
from pcmgn_jax.eval import bench

GOAL_S = 1.0


@dataclass(frozen=True)
class ExploreLatencyArgs(common.Outputs):
    workdir: str                 # run directory (config.json, training data, checkpoints)
    moves: int = 10              # timed slider moves
    mgn: bool = True             # the run's MGN among the predictors (--no_mgn: left out; the default is then kriging)


def designs(explorer, n: int, seed: int = 0) -> np.ndarray:
    """(n, P) designs [SI], seeded uniform over the sliders' ranges (in and out of the training box)."""
    lo, hi = np.array([p.slider_range() for p in explorer.params]).T
    return lo + np.random.default_rng(seed).random((n, len(lo))) * (hi - lo)


def time_moves(explorer, xs, *, default: bool) -> list[float]:
    """Seconds per move at each design of xs (module docstring: ``default`` or ``page``)."""
    out = []
    for x in xs:
        t0 = time.perf_counter()
        explorer.ask(x)
        json.dumps(explorer.view(x, show=explorer.default).figures)
        if default and explorer.default in explorer.deferred:
            explorer.predict_rest(x)
            json.dumps(explorer.view(x, show=explorer.default).figures)
        out.append(time.perf_counter() - t0)
    return out


def _stats(v: list[float]) -> dict:
    return {"median_s": statistics.median(v), "max_s": max(v), "n": len(v), "all_s": v}


def main(argv=None) -> int:
    from pcmgn_jax.explore import Explorer

    args = cli.parse(ExploreLatencyArgs, argv, description=__doc__, prog="python -m benchmarks.explore_latency")
    t0 = time.perf_counter()
    ex = Explorer(args.workdir, mgn=args.mgn)
    load_s = time.perf_counter() - t0
    xs = designs(ex, args.moves + 2)
    time_moves(ex, xs[:2], default=True)                      # warm-up (untimed)
    default = time_moves(ex, xs[2:], default=True)
    page = time_moves(ex, designs(ex, args.moves, seed=1), default=False)
    t0 = time.perf_counter()
    kr = Explorer(args.workdir, mgn=False, kinds=("kriging",), log=lambda s: None)
    kriging_load_s = time.perf_counter() - t0
    time_moves(kr, designs(kr, 2, seed=2), default=False)
    kriging = time_moves(kr, designs(kr, args.moves, seed=3), default=False)
    first = ex.query(ex.start)
    result = {"workdir": args.workdir, "default": ex.default, "deferred": ex.deferred, "seconds": ex.seconds,
              "mgn_rollout_s": ex.mgn_seconds, "predictors": ex.available, "n_nodes": first.n_nodes,
              "n_frames": first.n_frames, "load_s": load_s, "kriging_load_s": kriging_load_s,
              "default_move": _stats(default), "page_move": _stats(page), "kriging_move": _stats(kriging),
              "goal_s": GOAL_S, "goal_met_default": max(default) <= GOAL_S, "goal_met_kriging": max(kriging) <= GOAL_S,
              "command": cli.command_line("benchmarks.explore_latency", argv), "machine": bench.machine_info()}
    rows = [[f"default ({ex.default}" + (", after the page" if ex.default in ex.deferred else "") + ")",
             result["default_move"]["median_s"], result["default_move"]["max_s"]],
            ["page at once (the live predictors)", result["page_move"]["median_s"], result["page_move"]["max_s"]],
            ["kriging alone", result["kriging_move"]["median_s"], result["kriging_move"]["max_s"]]]
    md = (f"# explorer response time per slider move: {args.workdir}\n\n"
          f"{first.n_nodes} nodes x {first.n_frames} frames; predictors {', '.join(ex.available)}; "
          f"load {load_s:.1f} s; "
          f"MGN rollout {ex.mgn_seconds if ex.mgn_seconds is None else round(ex.mgn_seconds, 3)} s; "
          f"{args.moves} moves, warm; goal <= {GOAL_S} s\n\n"
          + common.md_table(["what", "median [s]", "max [s]"], rows)
          + f"\ncommand: `{result['command']}`\n")
    json_path, md_path = common.default_paths("explore_latency", args.json, args.md)
    common.write_outputs(result, json_path, md_path, md)
    return 0


if __name__ == "__main__":
    common.run(main)
