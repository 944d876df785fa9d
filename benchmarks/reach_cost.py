"""Cost of reach (issue 39): one training step's network and one rollout, per processor.

    python -m benchmarks.reach_cost [--preset cpu] [--latent 64] [--frames 100] [--repeats 5] [--json PATH] [--md PATH]
        [--formulations default,realtime]

Variants: local message passing with 8 and 15 steps, the multi-scale (bi-stride V-cycles, 4 levels) and
the attention processor (32 slices, 4 heads) with 8 steps (a global block after steps 4 and 8), each in
the default and the ``realtime`` (per-design) formulation. Model: EncodeProcessDecode at the preset's
size with RANDOM parameters (timing only: shapes, not values, set the cost); graph: the preset's
region-of-interest mesh of the default scene (:func:`benchmarks.rollout_throughput.rollout_setup`).

- ``train_ms``: forward + backward (``jax.value_and_grad`` of the mean squared output) of the network
  on one graph (the training step's network cost at ``batch_graphs=1``; the optimiser update and, for
  ``realtime``, the 7 extra decoder readouts of ``frames_per_sample`` are not in it);
- ``rollout_ms``: one jitted ``--frames``-frame rollout of one design (``pcmgn_jax.mgn.rollout.rollout``).
Timed after compilation (AOT), interleaved round-robin (:func:`benchmarks.bench.time_calls`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

from benchmarks import common
from benchmarks.rollout_throughput import GraphArgs, rollout_setup
from pcmgn_jax import cli
from pcmgn_jax.eval import bench

VARIANTS = {"local 8": (8, "local"), "local 15": (15, "local"), "multiscale 8": (8, "multiscale"),
            "attention 8": (8, "attention")}


@dataclass(frozen=True)
class ReachCostArgs(GraphArgs):
    repeats: int = 5                          # timed calls of each (median)
    formulations: str = "default,realtime"    # comma list of formulations (pcmgn_jax.mgn.formulation.FORMULATIONS)


def main(argv=None) -> dict:
    a = cli.parse(ReachCostArgs, argv, description=__doc__, prog="python -m benchmarks.reach_cost")
    import jax
    import jax.numpy as jnp

    from pcmgn_jax.mgn.formulation import FORMULATIONS
    from pcmgn_jax.mgn.normalization import normalize_graph
    from pcmgn_jax.mgn.rollout import input_graph, rollout

    blk = jax.block_until_ready
    fns, info, compile_s = {}, {}, {}
    for fname in a.formulations.split(","):
        for name, (steps, reach) in VARIANTS.items():
            form = FORMULATIONS[fname].replace(reach=reach)
            s = rollout_setup(a.preset, latent=a.latent, layers=steps, n_designs=1, formulation=form)
            spec, model = s["spec"], s["spec"].model
            one = tuple(x[0] for x in (s["points"], s["u0"], s["v0"], s["vm0"]))
            common_args = (s["params"], s["stats"], s["topology"], s["index"])
            g, _ = input_graph(form, s["topology"], s["index"], one[0], one[1], one[2])
            g = normalize_graph(s["stats"], g, s["topology"].node_type)
            grad = jax.jit(jax.value_and_grad(lambda p, g: jnp.mean(model.apply(p, g) ** 2)))
            key = f"{fname} / {name}"
            t0 = time.perf_counter()
            roll = rollout.lower(spec, a.frames, *common_args, *one).compile()
            compile_s[key] = time.perf_counter() - t0
            blk(grad(s["params"], g))
            fns[key + " train"] = (lambda grad=grad, p=s["params"], g=g: blk(grad(p, g)))
            fns[key + " rollout"] = (lambda roll=roll, c=common_args, one=one: blk(roll(*c, *one)))
            info[key] = {"params": int(sum(x.size for x in jax.tree.leaves(s["params"]))), "steps": steps,
                         "reach": reach, "formulation": fname, "nodes": s["n_nodes"]}
    times = bench.time_calls(fns, repeats=a.repeats, warmup=1)
    rows, result = [], {"preset": a.preset, "latent": a.latent, "frames": a.frames, "machine": bench.machine_info(),
                        "command": cli.command_line("benchmarks.reach_cost", argv), "variants": {}}
    for key, meta in info.items():
        tr, ro = times[key + " train"]["median_ms"], times[key + " rollout"]["median_ms"]
        result["variants"][key] = {**meta, "train_ms": tr, "rollout_ms": ro, "compile_s": compile_s[key]}
        rows.append([key, meta["params"], tr, ro, compile_s[key]])
    md = (f"Reach cost, preset {a.preset} (latent {a.latent}, {a.frames}-frame rollout, median of {a.repeats})\n\n"
          + common.md_table(["formulation / processor", "parameters", "train step network [ms]",
                             "rollout [ms]", "rollout compile [s]"], rows))
    json_path, md_path = common.default_paths("reach_cost", a.json, a.md)
    common.write_outputs(result, json_path, md_path, md)
    return result


if __name__ == "__main__":
    common.run(main)
