"""JAX MeshGraphNet (pcmgn_jax.mgn.model) against a plain-PyTorch reference on the same graph, same run.

    python -m benchmarks.mgn_vs_torch --nodes 800 --layers 8 --latent 64 [--json PATH] [--md PATH]
    python -m benchmarks.mgn_vs_torch --nodes 3000 --layers 15 --latent 128

The graph is a real region-of-interest crop of the project's quad mesh (default scene, ball pressed
into the cover glass so contact edges are active), normalised features, random targets. Both sides
get the same arrays and the same number of CPU threads (``--threads``, default: all usable cores;
XLA's CPU client uses all of them, torch.set_num_threads is set to match).

Timed (after warm-up, interleaved round-robin, median of ``--repeats``):
- JAX: jitted ``model.apply`` (forward); jitted Adam train step (value_and_grad + optax.adam, MSE),
  one step per dispatch and ``--scan`` steps per dispatch (lax.scan, as pcmgn_jax.train.loop does).
- PyTorch eager, edge MLP first layer as concat (MeshGraphNets/PyG style) and with the concat trick;
  forward under torch.inference_mode; train step = zero_grad + forward + MSE + backward + Adam.step.
- PyTorch ``torch.compile`` (inductor) of the concat variant, when ``--compile`` and it works offline.
The reference figure is the fastest PyTorch variant. Also measured: dense 1024^2 float32 matmul rate
(jnp.dot and torch.mm) and the achieved MLP-matmul FLOP rate as a fraction of it, XLA's scratch
buffer per call (``memory_analysis().temp_size_in_bytes``) and, per call of every timed function,
minor page faults and user / system CPU time (getrusage; the per-dispatch overhead of issue 14 was
the page faults of that scratch buffer, see pcmgn_jax/heap.py: ``PCMGN_KEEP_HEAP=0`` measures the
old behaviour).
"""
from __future__ import annotations

import os
import time
import traceback
from dataclasses import dataclass
from typing import Literal

from benchmarks import common
from pcmgn_jax import cli
from pcmgn_jax.eval import bench


@dataclass(frozen=True)
class MgnVsTorchArgs(common.Outputs):
    nodes: int = 800                  # graph nodes (a crop of the preset's mesh)
    layers: int = 8                   # message-passing steps
    latent: int = 64                  # latent size
    mlp_layers: int = 2               # hidden layers per MLP
    preset: Literal["auto", "tiny", "cpu", "paper"] = "auto"   # mesh preset of the crop
    repeats: int = 15                 # timed calls of each (median)
    warmup: int = 3                   # untimed calls first
    scan: int = 10                    # train steps per dispatch of the lax.scan variant
    # torch threads (0 = all usable cores, which is what XLA's CPU client uses; to limit both, run under taskset)
    threads: int = 0
    compile: Literal["on", "off"] = "on"   # also time torch.compile
    torch: bool = True                # the PyTorch side (--no_torch: JAX only)
    torch_1thread: bool = True        # the extra single-thread PyTorch variants (--no_torch_1thread: skip them)
    # op-kind breakdown of the JAX forward and train step (jax.profiler trace; benchmarks.bench.profile_ops)
    profile: bool = False


def prepare_jax(g: dict, a) -> tuple[dict, dict]:
    """Compiled JAX callables (each blocks on its result) and metadata."""
    import jax
    import jax.numpy as jnp
    import optax

    from pcmgn_jax.eval.bench import jraph_graph
    from pcmgn_jax.mgn.model import EncodeProcessDecode

    graph = jraph_graph(g)
    target = jnp.asarray(g["target"])
    model = EncodeProcessDecode(output_size=3, latent_size=a.latent, mlp_layers=a.mlp_layers,
                                message_passing_steps=a.layers)
    params = model.init(jax.random.PRNGKey(0), graph)
    tx = optax.adam(1e-3)

    def loss_fn(p, gr, y):
        return jnp.mean((model.apply(p, gr) - y) ** 2)

    def step(p, o, gr, y):
        loss, grads = jax.value_and_grad(loss_fn)(p, gr, y)
        upd, o = tx.update(grads, o, p)
        return optax.apply_updates(p, upd), o, loss

    def chunk(p, o, gr, y):
        def body(c, _):
            p, o, loss = step(*c, gr, y)
            return (p, o), loss
        (p, o), losses = jax.lax.scan(body, (p, o), None, length=a.scan)
        return p, o, losses

    fwd = jax.jit(model.apply)
    train = jax.jit(step, donate_argnums=(0, 1))
    train_k = jax.jit(chunk, donate_argnums=(0, 1))
    st = {"s": (jax.tree.map(jnp.copy, params), tx.init(params)),
          "k": (jax.tree.map(jnp.copy, params), tx.init(params))}

    def one():
        p, o, loss = train(*st["s"], graph, target)
        st["s"] = (p, o)
        return loss

    def k_steps():
        p, o, loss = train_k(*st["k"], graph, target)
        st["k"] = (p, o)
        return loss

    t0 = time.perf_counter()
    jax.block_until_ready((fwd(params, graph), one(), k_steps()))
    compile_s = time.perf_counter() - t0
    blk = jax.block_until_ready
    fns = {"jax/forward": lambda: blk(fwd(params, graph)), "jax/train_step": lambda: blk(one()),
           "jax/train_chunk": lambda: blk(k_steps())}
    n_params = sum(x.size for x in jax.tree.leaves(params))
    temp_mb = {name: f.lower(*args).compile().memory_analysis().temp_size_in_bytes / 1e6
               for name, f, args in (("forward", fwd, (params, graph)),
                                     ("train_step", train, (params, st["s"][1], graph, target)),
                                     ("train_chunk", train_k, (params, st["k"][1], graph, target)))}
    return fns, dict(scan_steps_per_dispatch=a.scan, compile_s=compile_s, n_params=int(n_params),
                     xla_temp_mb=temp_mb)


def jax_results(t: dict, meta: dict) -> dict:
    return dict(forward_ms=t["jax/forward"]["median_ms"], train_step_ms=t["jax/train_step"]["median_ms"],
                train_step_scan_ms=t["jax/train_chunk"]["median_ms"] / meta["scan_steps_per_dispatch"],
                **meta)


def prepare_torch(g: dict, a, threads: int) -> tuple[dict, dict, dict]:
    """PyTorch callables per variant (thread count set inside each call), variants, info."""
    import torch

    from benchmarks.torch_mgn import TorchMGN, make_train_step, torch_graph

    torch.manual_seed(0)
    tg = torch_graph(g)
    y = torch.from_numpy(g["target"])
    node_dim = g["nodes"].shape[1]
    edge_dims = {"mesh": g["mesh_features"].shape[1], "contact": g["contact_features"].shape[1]}
    kw = dict(latent=a.latent, mlp_layers=a.mlp_layers, steps=a.layers)
    thread_counts = sorted({threads, 1}, reverse=True) if a.torch_1thread else [threads]
    variants, fns, info = {}, {}, {}

    def with_threads(n, f):
        def call():
            torch.set_num_threads(n)
            return f()
        return call

    def add(name, fwd, step, n, **meta):
        fns[f"{name}/forward"] = with_threads(n, fwd)
        fns[f"{name}/train_step"] = with_threads(n, lambda: step(tg, y))
        variants[name] = dict(threads=n, **meta)

    for trick in (False, True):
        m_inf = TorchMGN(node_dim, edge_dims, concat_trick=trick, **kw).eval()
        m_tr = TorchMGN(node_dim, edge_dims, concat_trick=trick, **kw)
        info["n_params"] = sum(p.numel() for p in m_tr.parameters())

        def fwd(m=m_inf):
            with torch.inference_mode():
                return m(tg)
        for n in thread_counts:  # one optimizer per thread count: independent parameter trajectories
            m_n = TorchMGN(node_dim, edge_dims, concat_trick=trick, **kw) if n != thread_counts[0] else m_tr
            add(f"eager_{'concat_trick' if trick else 'concat'}_t{n}", fwd, make_train_step(m_n), n,
                concat_trick=trick, compiled=False)
    torch.set_num_threads(threads)
    if a.compile == "on":
        try:
            t0 = time.perf_counter()
            m_inf = TorchMGN(node_dim, edge_dims, concat_trick=False, **kw).eval()
            m_tr = TorchMGN(node_dim, edge_dims, concat_trick=False, **kw)
            c_inf, c_tr = torch.compile(m_inf), torch.compile(m_tr)
            step = make_train_step(m_tr, forward=c_tr)

            def cfwd():
                with torch.inference_mode():
                    return c_inf(tg)
            cfwd()
            step(tg, y)
            step(tg, y)
            add(f"compiled_concat_t{threads}", cfwd, step, threads, concat_trick=False, compiled=True,
                compile_s=time.perf_counter() - t0)
        except Exception as exc:  # noqa: BLE001 -- report, never fail the benchmark on it
            info["compile_error"] = f"{type(exc).__name__}: {str(exc).splitlines()[0][:300]}"
            traceback.print_exc(limit=2)
    return fns, variants, info


def os_profile(fns: dict, meta: dict, calls: int = 3) -> dict:
    """Per step (a lax.scan chunk divided by its steps): median minor page faults, user and system CPU
    ms over ``calls`` calls (getrusage of the whole process: XLA's and torch's threads included)."""
    import resource
    import statistics
    out = {}
    for name, f in fns.items():
        per = meta["scan_steps_per_dispatch"] if name == "jax/train_chunk" else 1
        rows = []
        for _ in range(calls):
            r0 = resource.getrusage(resource.RUSAGE_SELF)
            f()
            r1 = resource.getrusage(resource.RUSAGE_SELF)
            rows.append(((r1.ru_minflt - r0.ru_minflt) / per, (r1.ru_utime - r0.ru_utime) * 1e3 / per,
                         (r1.ru_stime - r0.ru_stime) * 1e3 / per))
        out[name] = dict(zip(("minor_faults", "user_ms", "sys_ms"),
                             (statistics.median(r[i] for r in rows) for i in range(3))))
    return out


def torch_results(t: dict, variants: dict, info: dict, threads: int) -> dict:
    import torch
    torch.set_num_threads(threads)
    for name in variants:
        variants[name].update(forward_ms=t[f"{name}/forward"]["median_ms"],
                              train_step_ms=t[f"{name}/train_step"]["median_ms"])
    same = [k for k in variants if variants[k]["threads"] == threads]
    best_f = min(same, key=lambda k: variants[k]["forward_ms"])
    best_t = min(same, key=lambda k: variants[k]["train_step_ms"])
    any_f = min(variants, key=lambda k: variants[k]["forward_ms"])
    any_t = min(variants, key=lambda k: variants[k]["train_step_ms"])
    res = dict(forward_ms=variants[best_f]["forward_ms"], forward_variant=best_f,
               train_step_ms=variants[best_t]["train_step_ms"], train_step_variant=best_t,
               best_any_threads=dict(forward_ms=variants[any_f]["forward_ms"], forward_variant=any_f,
                                     train_step_ms=variants[any_t]["train_step_ms"], train_step_variant=any_t),
               threads=threads, interop_threads=torch.get_num_interop_threads(),
               variants=variants, **info)
    return res


def main(argv=None) -> dict:
    a = cli.parse(MgnVsTorchArgs, argv, description=__doc__, prog="python -m benchmarks.mgn_vs_torch")
    threads = a.threads or len(os.sched_getaffinity(0))
    g = bench.bench_graph(a.nodes, a.preset)
    gi = g["info"]
    have_torch = False
    if a.torch:
        try:
            import torch  # noqa: F401
            have_torch = True
        except ImportError:
            print("torch is not installed (pip install torch==2.13.0, or the 'bench' extra); JAX only")
    if have_torch:
        import torch
        torch.set_num_threads(threads)
    flops = bench.mgn_flops(gi["n_nodes"], {"mesh": gi["n_mesh_edges"], "contact": gi["contact_capacity"]},
                             {"node": gi["node_feature_dim"], "mesh": g["mesh_features"].shape[1],
                              "contact": g["contact_features"].shape[1]},
                             latent=a.latent, mlp_layers=a.mlp_layers, steps=a.layers)
    mm_jax = bench.matmul_gflops_jax()
    fns, jmeta = prepare_jax(g, a)
    if have_torch:
        tfns, variants, tinfo = prepare_torch(g, a, threads)
        fns.update(tfns)
    # one interleaved round-robin over every implementation: load changes hit all alike
    t = bench.time_calls(fns, repeats=a.repeats, warmup=a.warmup)
    jres = jax_results(t, jmeta)
    jres["per_call_os"] = os_profile({k: f for k, f in fns.items() if k.startswith("jax/")}, jmeta)
    if a.profile:  # where the time goes, by XLA op kind [ms per call]: what bounds the fraction of peak
        jres["profile_ms"] = {k: bench.profile_ops(fns[f"jax/{k}"]) for k in ("forward", "train_step")}
    tres = torch_results(t, variants, tinfo, threads) if have_torch else None
    if tres:
        best = {f"{tres['forward_variant']}/forward", f"{tres['train_step_variant']}/train_step"}
        tres["per_call_os"] = os_profile({k: f for k, f in fns.items() if k in best}, jmeta)
    mm_torch = bench.matmul_gflops_torch() if have_torch else None
    mm_jax2 = bench.matmul_gflops_jax()  # again after, to see drift
    peak = max(mm_jax, mm_jax2)

    def rate(ms, fl):
        return fl / (ms * 1e-3) / 1e9

    jres["forward_gflops"] = rate(jres["forward_ms"], flops["forward"])
    jres["train_step_gflops"] = rate(jres["train_step_ms"], flops["train_step_approx"])
    jres["forward_fraction_of_matmul_peak"] = jres["forward_gflops"] / peak
    jres["train_step_fraction_of_matmul_peak"] = jres["train_step_gflops"] / peak
    ratios = {}
    if tres:
        for v in tres["variants"].values():
            fl = flops["forward"] if v["concat_trick"] else flops["forward_concat_variant"]
            v["forward_gflops"] = rate(v["forward_ms"], fl)
            v["train_step_gflops"] = rate(v["train_step_ms"], 3 * fl)
        ratios = {"forward_torch_over_jax": tres["forward_ms"] / jres["forward_ms"],
                  "train_step_torch_over_jax": tres["train_step_ms"] / jres["train_step_ms"],
                  "train_step_torch_over_jax_scan": tres["train_step_ms"] / jres["train_step_scan_ms"]}
        for name, v in tres["variants"].items():
            ratios[f"forward_{name}_over_jax"] = v["forward_ms"] / jres["forward_ms"]
            ratios[f"train_step_{name}_over_jax"] = v["train_step_ms"] / jres["train_step_ms"]
        b = tres["best_any_threads"]
        ratios["forward_best_any_threads_torch_over_jax"] = b["forward_ms"] / jres["forward_ms"]
        ratios["train_step_best_any_threads_torch_over_jax"] = b["train_step_ms"] / jres["train_step_ms"]
        ratios["goal_2x_met"] = bool(ratios["forward_torch_over_jax"] >= 2 and
                                     ratios["train_step_torch_over_jax"] >= 2)
        ratios["goal_2x_met_against_any_thread_count"] = bool(
            ratios["forward_best_any_threads_torch_over_jax"] >= 2 and
            ratios["train_step_best_any_threads_torch_over_jax"] >= 2)
    machine = bench.machine_info(threads if have_torch else None)
    from pcmgn_jax import heap
    machine.update(keep_heap=heap.applied(), threads=threads, matmul_1024_gflops_jax=mm_jax,
                   matmul_1024_gflops_jax_after=mm_jax2, matmul_1024_gflops_torch=mm_torch)
    config = dict(nodes_requested=a.nodes, layers=a.layers, latent=a.latent, mlp_layers=a.mlp_layers,
                  repeats=a.repeats, warmup=a.warmup, command=cli.command_line("benchmarks.mgn_vs_torch", argv), **gi)
    result = dict(jax=jres, torch=tres, config=config, ratios=ratios, flops=flops, machine=machine)

    md = [f"## MeshGraphNet: JAX vs PyTorch — {gi['n_nodes']} nodes, {gi['n_mesh_edges']} mesh + "
          f"{gi['contact_capacity']} contact edge slots, {a.layers} steps x latent {a.latent}\n",
          f"`{config['command']}` — {machine['cpu']}, {threads} threads, jax {machine['jax']}, "
          f"torch {machine.get('torch')}; dense matmul 1024² f32: jnp.dot {peak:.1f} GFLOP/s"
          + (f", torch.mm {mm_torch:.1f} GFLOP/s" if mm_torch else "") + "\n"]
    rows = [["JAX (jit)", jres["forward_ms"], jres["train_step_ms"], 1.0, 1.0,
             f"{100 * jres['forward_fraction_of_matmul_peak']:.0f}% / "
             f"{100 * jres['train_step_fraction_of_matmul_peak']:.0f}%"],
            [f"JAX (lax.scan, {a.scan} steps/dispatch)", "", jres["train_step_scan_ms"], "",
             jres["train_step_ms"] / jres["train_step_scan_ms"], ""]]
    if tres:
        for name, v in tres["variants"].items():
            rows.append([f"PyTorch {name}", v["forward_ms"], v["train_step_ms"],
                         v["forward_ms"] / jres["forward_ms"], v["train_step_ms"] / jres["train_step_ms"],
                         f"{100 * v['forward_gflops'] / peak:.0f}% / {100 * v['train_step_gflops'] / peak:.0f}%"])
    md.append(common.md_table(["implementation", "forward ms", "train step ms", "forward: x JAX time",
                               "train: x JAX time", "matmul-peak fraction fwd / train"], rows))
    if tres:
        md.append(f"\nBest PyTorch / JAX: forward {ratios['forward_torch_over_jax']:.2f}x, train step "
                  f"{ratios['train_step_torch_over_jax']:.2f}x (JAX scan: "
                  f"{ratios['train_step_torch_over_jax_scan']:.2f}x). 2x goal "
                  f"{'met' if ratios['goal_2x_met'] else 'NOT met'} (same thread count). Against the fastest "
                  f"PyTorch at any thread count: forward {ratios['forward_best_any_threads_torch_over_jax']:.2f}x, "
                  f"train step {ratios['train_step_best_any_threads_torch_over_jax']:.2f}x.\n")
    prof = dict(jres["per_call_os"], **(tres or {}).get("per_call_os", {}))
    md.append("\nXLA scratch buffer per call (MB): " + ", ".join(
        f"{k} {v:.1f}" for k, v in jmeta["xla_temp_mb"].items()) +
        f"; freed heap kept (pcmgn_jax.heap): {machine['keep_heap']}. Per step, median of 3 calls "
        "(process getrusage):\n")
    md.append(common.md_table(["call", "minor page faults", "user CPU ms", "system CPU ms"],
                              [[k, v["minor_faults"], v["user_ms"], v["sys_ms"]] for k, v in prof.items()]))
    if tres:
        if "compile_error" in tres:
            md.append(f"\ntorch.compile failed: {tres['compile_error']}\n")
    jp, mp = common.default_paths(f"mgn_vs_torch_n{a.nodes}_l{a.layers}_h{a.latent}", a.json, a.md)
    common.write_outputs(result, jp, mp, "".join(md))
    return result


if __name__ == "__main__":
    common.run(main)
