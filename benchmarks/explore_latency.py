"""Response time of the explorer per slider move (issue 27; goal <= 1 s with the run's default surrogate).

    python -m benchmarks.explore_latency --workdir runs/cpu [--moves 10] [--no-mgn] [--json PATH] [--md PATH]

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

import argparse
import json
import statistics
import sys
import time

import numpy as np

GOAL_S = 1.0


def _args(argv):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--workdir", required=True, help="run directory (config.json, training data, checkpoints)")
    p.add_argument("--moves", type=int, default=10, help="timed slider moves")
    p.add_argument("--no-mgn", action="store_true", help="leave the run's MGN out (its default is then kriging)")
    p.add_argument("--json", default=None)
    p.add_argument("--md", default=None)
    return p.parse_args(argv)


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
    from benchmarks.common import default_paths, machine_info, md_table, write_outputs
    from pcmgn_jax.explore import Explorer

    args = _args(argv)
    t0 = time.perf_counter()
    ex = Explorer(args.workdir, mgn=not args.no_mgn)
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
              "command": "python -m benchmarks.explore_latency " + " ".join(argv if argv is not None else sys.argv[1:]),
              "machine": machine_info()}
    rows = [[f"default ({ex.default}" + (", after the page" if ex.default in ex.deferred else "") + ")",
             result["default_move"]["median_s"], result["default_move"]["max_s"]],
            ["page at once (the live predictors)", result["page_move"]["median_s"], result["page_move"]["max_s"]],
            ["kriging alone", result["kriging_move"]["median_s"], result["kriging_move"]["max_s"]]]
    md = (f"# explorer response time per slider move: {args.workdir}\n\n"
          f"{first.n_nodes} nodes x {first.n_frames} frames; predictors {', '.join(ex.available)}; "
          f"load {load_s:.1f} s; MGN rollout {ex.mgn_seconds if ex.mgn_seconds is None else round(ex.mgn_seconds, 3)} s; "
          f"{args.moves} moves, warm; goal <= {GOAL_S} s\n\n"
          + md_table(["what", "median [s]", "max [s]"], rows)
          + f"\ncommand: `{result['command']}`\n")
    json_path, md_path = default_paths("explore_latency", args.json, args.md)
    write_outputs(result, json_path, md_path, md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
