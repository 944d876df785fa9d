"""Rollout throughput of the surrogate: one 100-frame rollout, and many designs per call (per-design s).

    python -m benchmarks.rollout_throughput [--preset cpu] [--latent 64] [--layers 8] [--frames 100]
        [--batches 8] [--union 8] [--repeats 3] [--profile] [--json PATH] [--md PATH]

Model: EncodeProcessDecode at the ``cpu`` training preset size (latent 64, 8 steps) with RANDOM
parameters (timing only: shapes, not values, set the cost; the contact buffer has a fixed capacity,
so wild random predictions cannot change the work). Graph: the preset's region-of-interest mesh of
the default scene (``pcmgn_jax.sim.mesh.roi``); designs: OCA1/OCA2 thicknesses on a grid.

Timed after compilation (AOT ``lower().compile()``, so compile time is reported separately), all
interleaved round-robin in one process (machine noise hits every path alike):
- ``rollout`` (one jitted lax.scan over all frames) for one design: the "one at a time" reference;
- the same rollout as a Python loop of the jitted single step (``rollout.jitted_step``);
- ``rollout_union``: ``--union`` designs as one padded disjoint-union graph (``mgn.batching``);
- ``rollout_batch``: ``--batches`` designs stacked and vmapped (the old path).
``--profile`` adds a per-op breakdown (jax.profiler trace of one jitted frame step, ops grouped by
XLA kind) of one design, the union and the vmap batch: where the vmap path loses its time.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from benchmarks import common
from pcmgn_jax import cli
from pcmgn_jax.eval import bench
from pcmgn_jax.presets import PresetName


@dataclass(frozen=True)
class GraphArgs(common.Outputs):
    """A random-parameter model on a preset's region-of-interest graph (also benchmarks.reach_cost's)."""

    preset: PresetName = "cpu"   # mesh preset (pcmgn_jax.presets.PRESETS); the graph is its ROI
    latent: int = 64             # latent size
    frames: int = 100            # rollout steps


@dataclass(frozen=True)
class RolloutThroughputArgs(GraphArgs):
    layers: int = 8              # message-passing steps
    mlp_layers: int = 2          # hidden layers per MLP
    batches: str = "8"           # vmap batch sizes (the old path), comma separated
    union: str = "8"             # disjoint-union batch sizes, comma separated
    repeats: int = 3             # timed calls of each (median)
    profile: bool = False        # per-op breakdown of one frame step (jax.profiler)
    loop: bool = True            # the Python-loop comparison (--no_loop: skip it)


def rollout_setup(preset: str, *, latent: int, layers: int, mlp_layers: int = 2, n_designs: int = 8,
                  seed: int = 0, formulation=None) -> dict:
    """Model spec, random params, stats, topology, contact index and per-design initial states.
    ``formulation``: a :class:`~pcmgn_jax.mgn.formulation.Formulation` (default: the project's default)."""
    import jax

    from pcmgn_jax.mgn.inputs import graph_inputs
    from pcmgn_jax.mgn.model import EncodeProcessDecode
    from pcmgn_jax.mgn.normalization import normalize_graph
    from pcmgn_jax.mgn.rollout import Spec, input_graph
    from pcmgn_jax.scene import default_scene
    from pcmgn_jax.sim.mesh import build_mesh, roi

    base = default_scene()
    side = int(np.ceil(np.sqrt(n_designs)))
    grid = np.linspace(50e-6, 150e-6, side)
    designs = [(a, b) for a in grid for b in grid][:n_designs]
    meshes = [roi(build_mesh(base.with_design(*d), preset), preset)[0] for d in designs]
    m0 = meshes[0]
    for m in meshes[1:]:
        if not np.array_equal(m.cells, m0.cells):
            raise ValueError("designs do not share one topology")
    from pcmgn_jax.mgn.formulation import FORMULATIONS
    form = formulation or FORMULATIONS["default"]
    ball = m0.node_part == 0
    # contact radius: the default (auto_radius); buffer sized on the ball pressed up to 20 µm into the
    # glass (a realistic peak)
    pressed = []
    for depth in (0.0, 10e-6, 20e-6):
        u = np.zeros_like(m0.points)
        u[ball, 1] = -(base.ball.gap + depth)
        pressed.append(m0.points + u)
    topo, index, _ = graph_inputs(m0, base, scene_features=form.scene_features, positions=[np.stack(pressed)],
                                  capacity_factor=2.0, levels=form.hierarchy_levels)
    radius = index.radius
    points = np.stack([m.points for m in meshes]).astype(np.float32)
    u0 = np.zeros_like(points)
    v0 = np.zeros_like(points)
    v0[:, ball, 1] = -base.ball.velocity
    vm0 = np.zeros(points.shape[:2], np.float32)
    # normalisation statistics from the pressed frame (means/stds of the right magnitudes; targets O(1))
    from pcmgn_jax.mgn.normalization import Accumulator, TypedAccumulator, make_stats
    g, _ = input_graph(form, topo, index, m0.points, pressed[-1] - m0.points, v0[0])
    k = topo.n_node_types
    node_type = np.asarray(topo.node_type)
    acc = {"node": TypedAccumulator(k, g.nodes.shape[1] - k), "mesh": TypedAccumulator(k, 6),
           "contact": Accumulator(3), "motion": TypedAccumulator(k, 2), "stress": TypedAccumulator(k, 1),
           "ball": Accumulator(2)}
    acc["node"].add(np.asarray(g.nodes[:, k:]), node_type)
    acc["mesh"].add(np.asarray(g.edges["mesh"].features), node_type[np.asarray(topo.mesh_receivers)])
    stats = make_stats(**acc, per_part=True, contact_default_std=radius)
    model = EncodeProcessDecode(output_size=form.output_size, latent_size=latent, mlp_layers=mlp_layers,
                                message_passing_steps=layers, decoder_condition=form.decoder_condition,
                                reach=form.reach, reach_levels=form.reach_levels, reach_slices=form.reach_slices,
                                reach_heads=form.reach_heads)
    spec = Spec(model=model, formulation=form, dt=float(base.output_dt))
    params = model.init(jax.random.PRNGKey(seed), normalize_graph(stats, g, node_type))
    return {"spec": spec, "params": params, "stats": stats, "topology": topo, "index": index, "points": points,
            "u0": u0, "v0": v0, "vm0": vm0, "n_nodes": int(m0.n_nodes),
            "n_mesh_edges": int(topo.mesh_senders.shape[0]), "contact_capacity": int(index.capacity),
            "designs_m": designs}


def _tile(x, b):
    reps = int(np.ceil(b / x.shape[0]))
    return np.concatenate([x] * reps)[:b]


def union_setup(s: dict, b: int):
    """``b`` designs of the setup (tiled) as a padded disjoint union: (GraphBatch, u0, v0, vm0)."""
    from pcmgn_jax.mgn.batching import batch_graphs, to_union
    pts, u0, v0, vm0 = (_tile(s[k], b) for k in ("points", "u0", "v0", "vm0"))
    batch = batch_graphs([s["topology"]] * b, [s["index"]] * b, list(pts))
    return (batch,) + tuple(to_union(batch, list(a)) for a in (u0, v0, vm0))


def _profile(spec, common_args, one, s, b: int) -> dict:
    """Op-kind breakdown of one frame step: one design, a union of ``b``, a vmap batch of ``b``."""
    import jax
    import jax.numpy as jnp

    from pcmgn_jax.mgn.rollout import step
    # everything passed as arguments (as in the rollouts), so that nothing is constant-folded
    single = jax.jit(lambda c, p, u, v: step(spec, *c, p, u, v)[:3])
    batch, ub, vb, _ = union_setup(s, b)
    union = jax.jit(lambda c, bt, u, v: step(spec, *c, bt.topology, bt.index, bt.points, u, v, bt.layout)[:3])
    stacked = [jnp.asarray(_tile(s[k], b)) for k in ("points", "u0", "v0")]
    vmapped = jax.jit(lambda c, p, u, v: jax.vmap(lambda p, u, v: step(spec, *c, p, u, v)[:3])(p, u, v))
    blk = jax.block_until_ready
    one = [jnp.asarray(x) for x in one[:3]]
    profile_ops = bench.profile_ops
    out = {"1 design": profile_ops(lambda: blk(single(common_args, *one))),
           f"union {b}": profile_ops(lambda: blk(union(common_args[:2], batch, ub, vb))),
           f"vmap {b}": profile_ops(lambda: blk(vmapped(common_args, *stacked)))}
    return {k: {op: ms / (1 if k == "1 design" else b) for op, ms in v.items()} for k, v in out.items()}


def main(argv=None) -> dict:
    a = cli.parse(RolloutThroughputArgs, argv, description=__doc__, prog="python -m benchmarks.rollout_throughput")
    import jax

    from pcmgn_jax.mgn.rollout import jitted_step, rollout, rollout_batch, rollout_union

    batches = [int(b) for b in a.batches.split(",") if b.strip()]
    unions = [int(b) for b in a.union.split(",") if b.strip()]
    s = rollout_setup(a.preset, latent=a.latent, layers=a.layers, mlp_layers=a.mlp_layers)
    spec, T = s["spec"], a.frames
    common_args = (s["params"], s["stats"], s["topology"], s["index"])
    one = tuple(x[0] for x in (s["points"], s["u0"], s["v0"], s["vm0"]))
    blk = jax.block_until_ready

    compile_s, fns, per_call = {}, {}, {}
    t0 = time.perf_counter()
    single = rollout.lower(spec, T, *common_args, *one).compile()
    compile_s["single"] = time.perf_counter() - t0
    fns["single"] = lambda: blk(single(*common_args, *one))
    per_call["single"] = 1
    union_info = {}
    for b in unions:
        batch, *init = union_setup(s, b)
        t0 = time.perf_counter()
        fn = rollout_union.lower(spec, T, s["params"], s["stats"], batch, *init).compile()
        compile_s[f"union{b}"] = time.perf_counter() - t0
        fns[f"union{b}"] = (lambda fn=fn, batch=batch, init=init: blk(fn(s["params"], s["stats"], batch, *init)))
        per_call[f"union{b}"] = b
        union_info[str(b)] = {"nodes": int(batch.points.shape[0]), "real_nodes": int(batch.n_node.sum()),
                              "mesh_edges": int(batch.topology.mesh_senders.shape[0]),
                              "graph_slots": int(batch.layout.n_node.shape[0]),
                              "contact_capacity_per_graph": int(batch.index.capacity)}
    for b in batches:
        args = tuple(_tile(x, b) for x in (s["points"], s["u0"], s["v0"], s["vm0"]))
        t0 = time.perf_counter()
        fn = rollout_batch.lower(spec, T, *common_args, *args).compile()
        compile_s[f"vmap{b}"] = time.perf_counter() - t0
        fns[f"vmap{b}"] = (lambda fn=fn, args=args: blk(fn(*common_args, *args)))
        per_call[f"vmap{b}"] = b
    if a.loop:
        pts, u, v = (jax.numpy.asarray(x) for x in one[:3])

        def loop():
            uu, vv = u, v
            for _ in range(T):
                uu, vv, vm, _ = jitted_step(spec, *common_args, pts, uu, vv)
            return blk((uu, vv, vm))
        fns["python_loop"] = loop
        per_call["python_loop"] = 1
    load0 = bench.machine_info()["load_avg_1min"]
    times = bench.time_calls(fns, repeats=a.repeats, warmup=1)
    ms = {k: times[k]["median_ms"] / per_call[k] for k in fns}  # per design
    ref = ms["single"]
    result = {"single": {"rollout_ms": ref, "per_frame_ms": ref / T, "compile_s": compile_s["single"],
                         "timing": times["single"]}}
    if a.loop:
        result["python_loop"] = {"rollout_ms": ms["python_loop"], "loop_over_scan": ms["python_loop"] / ref}
    result["union"] = {str(b): dict(batch=b, ms_per_design=ms[f"union{b}"], designs_per_s=1e3 / ms[f"union{b}"],
                                    speedup_vs_single=ref / ms[f"union{b}"],
                                    compile_s=compile_s[f"union{b}"], timing=times[f"union{b}"],
                                    **union_info[str(b)]) for b in unions}
    result["batched"] = {str(b): {"batch": b, "rollout_ms": times[f"vmap{b}"]["median_ms"],
                                  "ms_per_design": ms[f"vmap{b}"], "designs_per_s": 1e3 / ms[f"vmap{b}"],
                                  "speedup_vs_single": ref / ms[f"vmap{b}"], "compile_s": compile_s[f"vmap{b}"],
                                  "timing": times[f"vmap{b}"]} for b in batches}
    for b in unions:
        if str(b) in result["batched"]:
            result["union"][str(b)]["speedup_vs_vmap"] = ms[f"vmap{b}"] / ms[f"union{b}"]
    if a.profile and unions:
        result["profile_step_ms_per_design"] = _profile(spec, common_args, one, s, unions[0])
    config = {"preset": a.preset, "n_nodes": s["n_nodes"], "n_mesh_edges": s["n_mesh_edges"],
              "contact_capacity": s["contact_capacity"], "latent": a.latent, "layers": a.layers,
              "mlp_layers": a.mlp_layers, "frames": T, "repeats": a.repeats, "params": "random (timing only)",
              "command": cli.command_line("benchmarks.rollout_throughput", argv)}
    machine = bench.machine_info()
    machine["load_avg_1min_start"] = load0
    result.update(config=config, machine=machine)
    md = [(f"## Surrogate rollout throughput — {a.preset} ROI mesh ({s['n_nodes']} nodes, "
           f"{s['n_mesh_edges']} mesh edges), {a.layers} steps x latent {a.latent}, {T} frames, random params\n"),
          (f"`{config['command']}` — {machine['cpu']}, {machine['cores_usable']} cores, jax {machine['jax']}, "
           f"load {load0:.1f} -> {machine['load_avg_1min']:.1f}; interleaved, median of {a.repeats}\n\n"),
          f"One rollout (lax.scan): {ref:.1f} ms ({ref / T:.2f} ms/frame; compile {compile_s['single']:.1f} s).\n"]
    if "python_loop" in result:
        md.append(f"Python loop of jitted steps: {ms['python_loop']:.1f} ms = "
                  f"{result['python_loop']['loop_over_scan']:.2f}x the scan rollout.\n")
    rows = [["1 at a time (`rollout`)", 1, ref / 1e3, 1e3 / ref, 1.0, compile_s["single"]]]
    rows += [[f"disjoint union (`rollout_union`, {union_info[str(b)]['nodes']} padded nodes)", b,
              ms[f"union{b}"] / 1e3, 1e3 / ms[f"union{b}"], ref / ms[f"union{b}"], compile_s[f"union{b}"]]
             for b in unions]
    rows += [["vmap over a stacked batch (`rollout_batch`)", b, ms[f"vmap{b}"] / 1e3, 1e3 / ms[f"vmap{b}"],
              ref / ms[f"vmap{b}"], compile_s[f"vmap{b}"]] for b in batches]
    md.append("\n" + common.md_table(["path", "designs per call", "s / design", "designs / s",
                                      "speed-up per design vs 1 at a time", "compile s"], rows))
    if "profile_step_ms_per_design" in result:
        prof = result["profile_step_ms_per_design"]
        ops = sorted({op for v in prof.values() for op in v}, key=lambda op: -max(v.get(op, 0) for v in prof.values()))
        md.append("\nOne frame step by XLA op kind, ms per design (jax.profiler trace; thread time, so it "
                  "can exceed wall time):\n\n")
        md.append(common.md_table(["op kind"] + list(prof), [[op] + [prof[k].get(op, 0.0) for k in prof]
                                                              for op in ops[:10]]
                                  + [["total"] + [sum(v.values()) for v in prof.values()]]))
    jp, mp = common.default_paths("rollout_throughput", a.json, a.md)
    common.write_outputs(result, jp, mp, "".join(md))
    return result


if __name__ == "__main__":
    common.run(main)
