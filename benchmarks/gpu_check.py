"""One command for a GPU (or any device): the paper-size surrogate and solver on the default JAX device.

    python -m benchmarks.gpu_check [--json PATH] [--md PATH]       # <= 8 min on one GPU
    python -m benchmarks.gpu_check --smoke --json /tmp/g.json      # the same code, small, on a CPU (< 1 min)

Measured on ``jax.devices()[0]``, each after compilation (compile time reported separately):
- the dense float32 matmul rate of the device (``jnp.dot`` of two n x n matrices, ``--matmul-n``;
  default 8192 on an accelerator, 1024 on a CPU), the reference for the fractions below;
- the MeshGraphNet forward and Adam train step (one per dispatch, and ``--scan`` per dispatch) on the
  ROI graph of ``--preset`` (``benchmarks.mgn_vs_torch.prepare_jax``: the model, an MSE loss, Adam), as
  steps/s and as a fraction of the matmul rate (analytic MLP FLOPs, ``common.mgn_flops``; train = 3 x forward);
- one ``--frames`` rollout of the same model size with random parameters on the preset's ROI mesh
  (``pcmgn_jax.mgn.rollout.rollout``, set up by ``benchmarks.rollout_throughput.rollout_setup``);
- one solver trajectory of the ``--preset`` mesh (``benchmarks.solver_speed.timed_simulate``: a compile
  run, then the timed run).
Full size: ``--preset paper``, 15 x 128, 100 frames. ``--smoke``: preset tiny, 1 x 8, 3 frames, a
2-frame solver run, 256² matmul, and (when jax is not imported yet) XLA's quick compile options
(:data:`SMOKE_XLA_FLAGS`: compilation is most of a smoke run's time, and its timings mean nothing).
Prints one table; writes JSON (atomically) where ``--json`` says (default without ``--smoke``:
benchmarks/results/gpu_check.json) and the table beside it (``--md``).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from types import SimpleNamespace

FULL = {"preset": "paper", "latent": 128, "layers": 15, "frames": 100, "solver_frames": 0, "repeats": 5,
        "scan": 3, "matmul_n": 0}
SMOKE = {"preset": "tiny", "latent": 8, "layers": 1, "frames": 3, "solver_frames": 2, "repeats": 2, "scan": 2,
         "matmul_n": 256}
SMOKE_XLA_FLAGS = "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"  # ~1/3 less CPU


def _args(argv):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--smoke", action="store_true", help="the same code at small sizes (tests, CPU)")
    p.add_argument("--preset", help="mesh preset of the graph, rollout and solver (paper; smoke: tiny)")
    p.add_argument("--latent", type=int, help="latent size (128; smoke: 8)")
    p.add_argument("--layers", type=int, help="message-passing steps (15; smoke: 1)")
    p.add_argument("--frames", type=int, help="rollout frames (100; smoke: 3)")
    p.add_argument("--solver-frames", type=int, help="solver frames (0 = the scene's 100; smoke: 2)")
    p.add_argument("--repeats", type=int, help="timed calls of each (5; smoke: 2)")
    p.add_argument("--scan", type=int, help="train steps per dispatch of the lax.scan variant (3; smoke: 2)")
    p.add_argument("--matmul-n", type=int, help="matmul size (0 = 8192 on an accelerator, 1024 on a CPU)")
    p.add_argument("--json", default=None)
    p.add_argument("--md", default=None)
    a = p.parse_args(argv)
    for k, v in (SMOKE if a.smoke else FULL).items():
        if getattr(a, k) is None:
            setattr(a, k, v)
    return a


def device_info() -> dict:
    import jax
    d = jax.devices()[0]
    return {"backend": jax.default_backend(), "platform": d.platform, "kind": d.device_kind,
            "device_count": jax.device_count(),
            "matmul_precision": str(jax.config.jax_default_matmul_precision)}


def train_and_forward(a, n_nodes: int) -> dict:
    """Forward, train step (1 and ``a.scan`` per dispatch) on a crop of ~``n_nodes`` nodes of the preset's
    mesh (ball pressed into the glass, so contact edges are live), with the FLOPs of each."""
    from benchmarks import common
    from benchmarks.mgn_vs_torch import jax_results, prepare_jax

    g = common.bench_graph(n_nodes, a.preset)
    gi = g["info"]
    fns, meta = prepare_jax(g, SimpleNamespace(latent=a.latent, layers=a.layers, mlp_layers=2, scan=a.scan))
    res = jax_results(common.time_calls(fns, repeats=a.repeats, warmup=1), meta)
    flops = common.mgn_flops(gi["n_nodes"], {"mesh": gi["n_mesh_edges"], "contact": gi["contact_capacity"]},
                             {"node": gi["node_feature_dim"], "mesh": g["mesh_features"].shape[1],
                              "contact": g["contact_features"].shape[1]},
                             latent=a.latent, mlp_layers=2, steps=a.layers)
    res.update(n_nodes=gi["n_nodes"], n_mesh_edges=gi["n_mesh_edges"], flops=flops,
               train_steps_per_s=1e3 / res["train_step_ms"], train_steps_per_s_scan=1e3 / res["train_step_scan_ms"])
    return res


def rollout_time(a) -> dict:
    """One ``a.frames`` rollout (lax.scan) of one design on the preset's ROI mesh, random parameters."""
    import jax

    from benchmarks import common
    from benchmarks.rollout_throughput import rollout_setup
    from pcmgn_jax.mgn.rollout import rollout

    s = rollout_setup(a.preset, latent=a.latent, layers=a.layers, n_designs=1)
    args = (s["params"], s["stats"], s["topology"], s["index"]) + tuple(s[k][0] for k in ("points", "u0", "v0", "vm0"))
    t0 = time.perf_counter()
    fn = rollout.lower(s["spec"], a.frames, *args).compile()
    compile_s = time.perf_counter() - t0
    t = common.time_calls({"rollout": lambda: jax.block_until_ready(fn(*args))}, repeats=a.repeats, warmup=1)
    ms = t["rollout"]["median_ms"]
    return {"frames": a.frames, "s": ms / 1e3, "ms_per_frame": ms / a.frames, "compile_s": compile_s,
            "n_nodes": s["n_nodes"], "timing": t["rollout"]}


def solver_time(a) -> dict:
    """One solver trajectory of the preset's mesh (one design; compile run, then the timed run)."""
    from benchmarks.solver_speed import designs, timed_simulate
    from pcmgn_jax.scene import default_scene

    base = default_scene()
    return timed_simulate([base.with_design(*designs(1)[0])], a.preset, a.solver_frames or base.n_frames)


def main(argv=None) -> dict:
    a = _args(sys.argv[1:] if argv is None else argv)
    if a.smoke and "jax" not in sys.modules:        # XLA reads its flags when jax starts
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {SMOKE_XLA_FLAGS}".strip()
    import jax

    from benchmarks import common
    from pcmgn_jax.atomic import atomic_write_text

    t_start = time.perf_counter()
    dev = device_info()
    n = a.matmul_n or (1024 if dev["backend"] == "cpu" else 8192)
    peak = common.matmul_gflops_jax(n, repeats=max(a.repeats, 3))
    roll = rollout_time(a)
    mgn = train_and_forward(a, roll["n_nodes"])                  # the rollout's node count
    for key, ms, fl in (("forward", mgn["forward_ms"], mgn["flops"]["forward"]),
                        ("train_step", mgn["train_step_ms"], mgn["flops"]["train_step_approx"]),
                        ("train_step_scan", mgn["train_step_scan_ms"], mgn["flops"]["train_step_approx"])):
        mgn[f"{key}_gflops"] = fl / (ms * 1e-3) / 1e9
        mgn[f"{key}_fraction_of_matmul"] = mgn[f"{key}_gflops"] / peak
    sol = solver_time(a)
    cmd = "python -m benchmarks.gpu_check " + " ".join(sys.argv[1:] if argv is None else argv)
    result = {"device": dev, "matmul": {"n": n, "gflops": peak}, "mgn": mgn, "rollout": roll, "solver": sol,
              "config": {**{k: getattr(a, k) for k in FULL}, "smoke": a.smoke, "mlp_layers": 2, "command": cmd},
              "machine": common.machine_info(), "total_s": time.perf_counter() - t_start}
    rows = [["dense matmul", f"{n}² float32 jnp.dot", peak, "GFLOP/s", ""],
            ["MGN forward", f"{mgn['n_nodes']} nodes, {a.layers} x {a.latent}", mgn["forward_ms"], "ms",
             f"{100 * mgn['forward_fraction_of_matmul']:.0f} %"],
            ["train step, 1 per dispatch", "model + MSE + Adam", mgn["train_steps_per_s"], "steps/s",
             f"{100 * mgn['train_step_fraction_of_matmul']:.0f} %"],
            [f"train step, {a.scan} per dispatch", "lax.scan", mgn["train_steps_per_s_scan"], "steps/s",
             f"{100 * mgn['train_step_scan_fraction_of_matmul']:.0f} %"],
            ["MGN rollout", f"{roll['frames']} frames, {roll['n_nodes']} nodes (compile {roll['compile_s']:.1f} s)",
             roll["s"], "s", ""],
            ["solver trajectory", (f"{a.preset} mesh, {sol['n_frames']} frames x {sol['n_sub_per_frame']} substeps "
             f"(compile {sol['compile_s']:.1f} s)"), sol["wall_s"], "s", ""],
            ["whole check", "", result["total_s"], "s", ""]]
    md = (f"## GPU check — {dev['platform']} {dev['kind']} (jax {jax.__version__}, {dev['device_count']} "
          f"device(s))\n\n`{cmd}`\n\n" + common.md_table(["what", "size", "value", "unit", "of the matmul rate"], rows))
    print(md)
    json_path = Path(a.json) if a.json else (None if a.smoke else common.RESULTS / "gpu_check.json")
    if json_path is not None:
        md_path = Path(a.md) if a.md else json_path.with_suffix(".md")
        for path, text in ((json_path, json.dumps(common._clean(result), indent=1, allow_nan=False) + "\n"),
                           (md_path, md)):
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(path, text)
        print(f"wrote {json_path} and {md_path}")
    return result


if __name__ == "__main__":
    main()
