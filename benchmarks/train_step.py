"""The project's training step as the training loop runs it (issue 49): what one optimiser step spends its time on.

    python -m benchmarks.train_step --preset cpu [--dataset_dir data/cpu] [--formulation realtime] [--repeats 5]
        [--train_flags="--batch_graphs=2 --seed=1"] [--no_split]
        [--json results/benchmarks/train_step_cpu.json] [--md results/benchmarks/train_step_cpu.md]

Built with the training code itself (``pcmgn_jax.train``), on the dataset's training split (``load_splits``: the solver
never runs here; a missing dataset is an error): the preset's config with ``--formulation`` and ``--train_flags``
over it (``cli.parse_config``, the training flags), sized to a generated dataset as ``experiments.train`` does
(``fit_to_dataset``); ``setup.prepare`` (graphs, contact buffer, union size bucket, normaliser statistics);
``loop.init_params`` and ``step.init_state`` (Adam, the parameters' moving average when ``ema_decay`` > 0);
``loop.chunk_batch`` (one dispatch's host batch: data order and padded unions, ``frames_per_sample`` frames per
sample) and ``step.train_chunk`` (``steps_per_dispatch`` optimiser steps in one ``lax.scan``), compiled once (AOT)
and called as the loop calls it. After ``--warmup`` dispatches, median of ``--repeats``:

- per dispatch and per optimiser step (/ steps_per_dispatch): the loop's host work (gathering the batch), its
  transfer to the device (``jax.device_put``) and the device call (train_chunk, blocked on its state and metrics);
- XLA's FLOPs of one step: the compiled chunk's ``cost_analysis`` (XLA counts a while loop's body once: checked
  on the programs of a K-step and a one-step chunk before optimisation, ``xla_counts_loop_body_once``; were it K
  times, the count is divided by K); the achieved GFLOP/s and its fraction of the dense 1024² float32 ``jnp.dot``
  rate measured in the same run (``bench.matmul_gflops_jax``, before and after: the higher);
- with ``--split`` (default): the loss alone (``step.batch_loss``: forward), its ``value_and_grad`` (+ backward) and
  train_chunk with one step (+ Adam, EMA, one dispatch) on one batch, timed interleaved with the chunk;
- with ``--profile`` (default): the XLA op profile (``bench.profile_ops``: self time per op kind, ms of thread
  time) of one dispatch per step, and of the loss and value_and_grad, in ``bench.OP_KIND_GROUPS``.
"""
from __future__ import annotations

import shlex
import time
from dataclasses import dataclass

from benchmarks import common
from pcmgn_jax import cli
from pcmgn_jax.eval import bench
from pcmgn_jax.presets import PresetName

T0 = time.perf_counter()


@dataclass(frozen=True)
class TrainStepArgs(common.Outputs):
    preset: PresetName = "cpu"   # training preset: the config (and dataset, data/<data_preset>) the loop runs
    dataset_dir: str = ""        # the dataset (default: the preset's, data/<data_preset>); it must exist
    formulation: str = ""        # "" = the preset's; paper | default | dynamic | realtime (experiments.train's flag)
    # more training flags, as experiments.train takes them; written with '=': --train_flags="--batch_graphs=2 --seed=1"
    train_flags: str = ""
    repeats: int = 5             # timed dispatches (median)
    warmup: int = 1              # untimed dispatches after compilation
    split: bool = True           # time the loss, its value_and_grad and a one-step chunk (--no_split: the chunk only)
    profile: bool = True         # XLA op-kind profile (--no_profile: skip)
    profile_repeats: int = 1     # traced dispatches of the op profile


def say(msg: str) -> None:
    print(f"[train_step {time.perf_counter() - T0:6.1f} s] {msg}", flush=True)


def training_config(a: TrainStepArgs):
    """The run config ``experiments.train`` would train with these flags, and the flags."""
    from pcmgn_jax.train.pipeline import fit_to_dataset
    flags = ["--preset", a.preset] + (["--formulation", a.formulation] if a.formulation else []) + \
        shlex.split(a.train_flags) + (["--dataset_dir", a.dataset_dir] if a.dataset_dir else [])
    return fit_to_dataset(cli.parse_config(flags), given=cli.given_flags(flags)), flags


def cost(compiled) -> dict:
    """XLA's cost analysis (flops, bytes accessed, transcendentals) and scratch buffer [MB] of a compiled call."""
    ca = compiled.cost_analysis()
    ca = (ca[0] if isinstance(ca, (list, tuple)) else ca) or {}
    return {"flops": float(ca.get("flops", 0.0)), "bytes_accessed": float(ca.get("bytes accessed", 0.0)),
            "transcendentals": float(ca.get("transcendentals", 0.0)),
            "temp_mb": compiled.memory_analysis().temp_size_in_bytes / 1e6}


def prepare_run(a: TrainStepArgs, cfg) -> dict:
    """Training data, setup, state, the host batches of ``warmup + repeats`` dispatches (each gathered and sent
    to the device, both timed) and train_chunk compiled: what the loop holds before its first dispatch."""
    import jax

    from pcmgn_jax.data.splits import load_splits
    from pcmgn_jax.train.loop import chunk_batch, init_params
    from pcmgn_jax.train.pipeline import network_trajectories
    from pcmgn_jax.train.sampling import pair_table
    from pcmgn_jax.train.setup import prepare
    from pcmgn_jax.train.sharding import data_parallel
    from pcmgn_jax.train.step import init_state, train_chunk
    if data_parallel(cfg.devices, cfg.batch_graphs) is not None:
        raise ValueError(f"devices={cfg.devices}: this benchmark times one device (--train_flags=--devices=1)")
    train, val = network_trajectories(cfg, *load_splits(cfg.resolved_dataset_dir, n_train=cfg.n_train,
                                                        n_val=cfg.n_val, n_test=0)[:2])
    say(f"{len(train)} training trajectories from {cfg.resolved_dataset_dir}; preparing (statistics, graphs)")
    t0 = time.perf_counter()
    setup = prepare(cfg, train)
    state = init_state(setup.spec, init_params(setup, train[0], cfg.seed))
    jax.block_until_ready(state)
    setup_s = time.perf_counter() - t0
    say(f"setup {setup_s:.1f} s: union of {setup.sizes.nodes} nodes, {setup.sizes.edges} mesh edges, "
        f"contact buffer {setup.sizes.capacity}; gathering {a.warmup + a.repeats} dispatches' batches")
    table, K = pair_table(train), cfg.steps_per_dispatch
    seed_key = jax.random.PRNGKey(cfg.seed + 1)  # the loop's noise key
    gather_ms, put_ms, batches = [], [], []
    for i in range(max(a.warmup, 0) + a.repeats):
        t0 = time.perf_counter()
        host = chunk_batch(cfg, setup, train, table, i * K)
        t1 = time.perf_counter()
        batches.append(jax.block_until_ready(jax.device_put(host)))
        gather_ms.append((t1 - t0) * 1e3)
        put_ms.append((time.perf_counter() - t1) * 1e3)
    say(f"compiling train_chunk ({K} steps per dispatch)")
    t0 = time.perf_counter()
    lowered = train_chunk.lower(setup.spec, state, setup.stats, batches[0], seed_key)
    chunk = lowered.compile()
    compile_s = {"train_chunk": time.perf_counter() - t0}
    say(f"compiled in {compile_s['train_chunk']:.1f} s")
    n_params = int(sum(x.size for x in jax.tree.leaves(state.params)))
    return dict(train=train, setup=setup, state=state, seed_key=seed_key, batches=batches, chunk=chunk, lowered=lowered,
                compile_s=compile_s, setup_s=setup_s, n_params=n_params,
                gather_ms=gather_ms[a.warmup:], put_ms=put_ms[a.warmup:])


def callables(a: TrainStepArgs, r: dict) -> tuple[dict, dict]:
    """The timed zero-argument calls (each blocks on its result) and XLA's costs of each. ``train_chunk``: one
    dispatch, the state carried on as in the loop, the batches taken in turn; with ``--split`` also train_chunk on
    one step, the loss and its value_and_grad, on the first step's batch with the initial parameters."""
    import jax

    from pcmgn_jax.train.step import batch_loss, train_chunk
    setup, state, key, chunk, batches = r["setup"], r["state"], r["seed_key"], r["chunk"], r["batches"]
    carry = {"state": state, "i": 0, "overflow": False}

    def dispatch():
        new, m = chunk(carry["state"], setup.stats, batches[carry["i"] % len(batches)], key)
        m = jax.device_get(m)        # as the loop does after every dispatch (blocks on the call)
        carry["state"], carry["i"] = new, carry["i"] + 1
        carry["overflow"] |= bool(m["overflow"].any())
        return m

    fns, costs = {"train_chunk": dispatch}, {"train_chunk": cost(chunk)}
    one = jax.tree.map(lambda x: x[:1], batches[0])              # a one-step chunk
    lowered = {"K": r["lowered"], "1": train_chunk.lower(setup.spec, state, setup.stats, one, key)}
    counts = {n: (lo.cost_analysis() or {}).get("flops", 0.0) for n, lo in lowered.items()}
    # XLA counts a while loop's body once (jax 0.10: the K-step chunk's count is one step's); were it K times, / K
    r["loop_body_once"] = counts["K"] < 1.5 * counts["1"]
    if a.split:
        say("compiling train_chunk on one step")
        t0 = time.perf_counter()
        step1 = lowered["1"].compile()
        r["compile_s"]["train_chunk_1"] = time.perf_counter() - t0
        costs["train_chunk_1"] = cost(step1)
        fns["train_chunk_1"] = lambda: jax.block_until_ready(step1(state, setup.stats, one, key))
        b1 = jax.tree.map(lambda x: x[0], batches[0])            # one step's unions (S, ...)
        args = (state.params, setup.spec, setup.stats, b1, jax.random.fold_in(key, state.step), state.step)
        for name, fn in (("loss", batch_loss), ("value_and_grad", jax.value_and_grad(batch_loss, has_aux=True))):
            say(f"compiling {name}")
            t0 = time.perf_counter()
            c = jax.jit(fn, static_argnums=1).lower(*args).compile()
            r["compile_s"][name] = time.perf_counter() - t0
            costs[name] = cost(c)
            fns[name] = (lambda c=c: jax.block_until_ready(c(*args[:1], *args[2:])))
    r["carry"] = carry
    return fns, costs


def split_rows(t: dict, K: int) -> dict:
    """Per optimiser step [ms]: the chunk's per-step time, and with ``--split`` one step alone: forward (loss),
    backward (value_and_grad - loss), update and dispatch (a one-step chunk - value_and_grad: Adam, EMA, the
    scan of one, the call)."""
    ms = {k: v["median_ms"] for k, v in t.items()}
    out = {"train_step_in_chunk": ms["train_chunk"] / K}
    if "loss" in ms:
        out.update(forward=ms["loss"], backward=ms["value_and_grad"] - ms["loss"],
                   update_and_dispatch=ms["train_chunk_1"] - ms["value_and_grad"],
                   value_and_grad=ms["value_and_grad"], train_step_1_per_dispatch=ms["train_chunk_1"])
    return out


def profiles(a: TrainStepArgs, fns: dict, K: int, device_ms_per_step: float) -> dict:
    """The op profiles [ms of thread time per step] grouped (bench.group_ops), with the raw kinds."""
    out = {}
    jobs = [("train_step", fns["train_chunk"], a.profile_repeats, K)]
    jobs += [(n, fns[n], 3, 1) for n in ("loss", "value_and_grad") if n in fns]
    for name, fn, reps, per in jobs:
        say(f"profiling {name} ({reps} traced call{'s' if reps > 1 else ''})")
        raw = {k: v / per for k, v in bench.profile_ops(fn, repeats=reps).items()}
        out[name] = {"thread_ms": sum(raw.values()), "groups": bench.group_ops(raw), "kinds_ms": raw}
    tr = out["train_step"]
    tr["thread_over_wall"] = tr["thread_ms"] / device_ms_per_step  # > 1: ops ran side by side on the cores
    return out


LABELS = {"host_gather": "host: the batch (loop.chunk_batch)", "transfer": "transfer (jax.device_put)",
          "device": "device: train_chunk", "total": "total", "loss": "forward (loss)",
          "train_step": "train step (chunk / K)", "value_and_grad": "value_and_grad"}


def markdown(res: dict) -> str:
    c, s, x, K = res["config"], res["per_step_ms"], res["xla"], res["config"]["steps_per_dispatch"]
    d, m = res["per_dispatch_ms"], res["machine"]
    md = [f"## Training step, preset {c['preset']} ({c['formulation']}: processor {c['processor']}, "
          f"{c['frames_per_sample']} frame(s) per sample, {c['batch_graphs']} graph(s) per step, {K} steps per "
          f"dispatch, {c['message_passing_steps']} x {c['latent_size']}, EMA {c['ema_decay']:g})\n\n",
          f"`{c['command']}`: {m['cpu']}, jax {m['jax']}, load {m['load_avg_1min'] or 0:.2f}; union of "
          f"{c['union_nodes']} nodes, {c['union_mesh_edges']} mesh edges, contact buffer {c['contact_capacity']}; "
          f"dense matmul 1024² f32 (jnp.dot) {res['matmul_gflops']:.1f} GFLOP/s; median of {c['repeats']}.\n\n"]
    rows = [[LABELS[k], d[k], s[k], s[k] / s["total"]] for k in ("host_gather", "transfer", "device", "total")]
    md.append(common.md_table(["per dispatch", "ms / dispatch", "ms / step", "share"], rows))
    md.append(f"\nXLA FLOPs per step {res['flops_per_step'] / 1e9:.4g} G: {res['gflops']['device']:.1f} GFLOP/s "
              f"on the device call = **{100 * res['fraction_of_matmul']['device']:.0f} %** of the dense-matmul rate "
              f"({100 * res['fraction_of_matmul']['wall']:.0f} % with the host work). Compile: "
              + ", ".join(f"{k} {v:.1f} s" for k, v in res["compile_s"].items()) + ".\n")
    sp = res["split_ms"]
    if "forward" in sp:
        one = sp["train_step_1_per_dispatch"]
        rows = [[name, sp[k], x[n]["flops"] / 1e9, x[n]["flops"] / (sp[k] * 1e6), sp[k] / one]
                for name, k, n in (("forward (loss)", "forward", "loss"),
                                   ("forward + backward (value_and_grad)", "value_and_grad", "value_and_grad"),
                                   ("train_chunk, 1 step per dispatch", "train_step_1_per_dispatch", "train_chunk_1"))]
        md.append("\nOne step on one batch:\n\n" + common.md_table(
            ["call", "ms", "XLA GFLOP", "GFLOP/s", "x the 1-step dispatch"], rows))
        md.append(f"\nSplit of a one-step dispatch: forward {sp['forward']:.4g} ms, backward {sp['backward']:.4g} ms, "
                  f"update + dispatch {sp['update_and_dispatch']:.4g} ms; in the {K}-step chunk a step takes "
                  f"{sp['train_step_in_chunk']:.4g} ms.\n")
    prof = res.get("profile")
    if prof:
        names = [n for n in ("loss", "value_and_grad", "train_step") if n in prof]
        groups = list(dict.fromkeys(g for n in ("train_step", *names) for g in prof[n]["groups"]))
        rows = [[g] + [prof[n]["groups"].get(g, {}).get("ms", 0.0) for n in names]
                + [prof["train_step"]["groups"].get(g, {}).get("share", 0.0)] for g in groups]
        rows.append(["total (thread time)"] + [prof[n]["thread_ms"] for n in names] + [1.0])
        md.append(f"\nXLA op profile, ms of thread time per step (self time per op kind; the train step's thread time "
                  f"is {prof['train_step']['thread_over_wall']:.2f}x its device time):\n\n")
        md.append(common.md_table(["op kinds"] + [LABELS[n] for n in names] + ["share of the train step"], rows))
    if res["contact_overflow"]:
        md.append("\nNote: the contact buffer overflowed in a timed dispatch (the loop would grow it and re-run).\n")
    return "".join(md)


def main(argv=None) -> dict:
    import statistics
    a = cli.parse(TrainStepArgs, argv, description=__doc__, prog="python -m benchmarks.train_step")
    if a.repeats < 1 or a.warmup < 0 or a.profile_repeats < 1:
        raise ValueError("--repeats and --profile_repeats must be >= 1, --warmup >= 0")
    cfg, flags = training_config(a)
    say(f"config: preset {cfg.preset}, formulation {cfg.formulation_name} (processor {cfg.formulation.processor}), "
        f"{cfg.frames} frame(s) per sample, {cfg.steps_per_dispatch} steps per dispatch")
    mm0 = bench.matmul_gflops_jax()
    say(f"dense matmul 1024² f32: {mm0:.1f} GFLOP/s")
    r = prepare_run(a, cfg)
    K = cfg.steps_per_dispatch
    fns, costs = callables(a, r)
    say(f"timing {list(fns)}: {a.warmup} warm-up + {a.repeats} interleaved rounds")
    t = bench.time_calls(fns, repeats=a.repeats, warmup=a.warmup)
    gather, put = statistics.median(r["gather_ms"]), statistics.median(r["put_ms"])
    device = t["train_chunk"]["median_ms"]
    per_dispatch = {"host_gather": gather, "transfer": put, "device": device, "total": gather + put + device}
    per_step = {k: v / K for k, v in per_dispatch.items()}
    say(f"per step: device {per_step['device']:.2f} ms, host {per_step['host_gather']:.2f} ms, "
        f"transfer {per_step['transfer']:.2f} ms")
    prof = profiles(a, fns, K, per_step["device"]) if a.profile else None
    mm1 = bench.matmul_gflops_jax()
    peak = max(mm0, mm1)
    flops = costs["train_chunk"]["flops"] / (1 if r["loop_body_once"] else K)
    gflops = {k: flops / (per_step[k] * 1e6) for k in ("device", "total")}
    setup, sizes = r["setup"], r["setup"].sizes
    machine = bench.machine_info()
    machine.update(matmul_1024_gflops_jax=mm0, matmul_1024_gflops_jax_after=mm1)
    config = dict(command=cli.command_line("benchmarks.train_step", argv), training_flags=flags, preset=cfg.preset,
                  formulation=cfg.formulation_name, processor=cfg.formulation.processor, frames_per_sample=cfg.frames,
                  batch_graphs=cfg.batch_graphs, steps_per_dispatch=K, ema_decay=cfg.ema_decay,
                  lambda_pen=cfg.lambda_pen, latent_size=cfg.latent_size, mlp_layers=cfg.mlp_layers,
                  message_passing_steps=cfg.message_passing_steps, dataset_dir=cfg.resolved_dataset_dir,
                  n_train=len(r["train"]), n_pairs=setup.n_pairs, n_params=r["n_params"], union_nodes=sizes.nodes,
                  union_mesh_edges=sizes.edges, contact_capacity=sizes.capacity, repeats=a.repeats, warmup=a.warmup,
                  split=a.split, profile=a.profile, train_config=cfg.to_dict())
    result = dict(config=config, machine=machine, matmul_gflops=peak, setup_s=r["setup_s"], compile_s=r["compile_s"],
                  per_dispatch_ms=per_dispatch, per_step_ms=per_step, host_share=(gather + put) / per_dispatch["total"],
                  xla=costs, flops_per_step=flops, xla_counts_loop_body_once=r["loop_body_once"],
                  gflops=dict(device=gflops["device"], wall=gflops["total"]),
                  fraction_of_matmul=dict(device=gflops["device"] / peak, wall=gflops["total"] / peak),
                  split_ms=split_rows(t, K), timings=t, profile=prof, contact_overflow=r["carry"]["overflow"])
    jp, mp = common.default_paths(f"train_step_{cfg.preset}", a.json, a.md)
    common.write_outputs(result, jp, mp, markdown(result))
    return result


if __name__ == "__main__":
    common.run(main)
