"""One command for a GPU (or any device): the paper-size surrogate and solver on the default JAX device.

    python -m benchmarks.gpu_check [--json PATH] [--md PATH]       # <= 8 min on one GPU
    python -m benchmarks.gpu_check --smoke --json /tmp/g.json      # the same code, small, on a CPU (< 1 min)

Measured on ``jax.devices()[0]``, each after compilation (compile time reported separately):
- the dense float32 matmul rate of the device (``jnp.dot`` of two n x n matrices, ``--matmul_n``;
  default 8192 on an accelerator, 1024 on a CPU), the reference for the fractions below;
- the MeshGraphNet forward and Adam train step (one per dispatch, and ``--scan`` per dispatch) on the
  ROI graph of ``--preset`` (``benchmarks.mgn_vs_torch.prepare_jax``: the model, an MSE loss, Adam), as
  steps/s and as a fraction of the matmul rate (analytic MLP FLOPs, ``bench.mgn_flops``; train = 3 x forward);
- one ``--frames`` rollout of the same model size with random parameters on the preset's ROI mesh
  (``pcmgn_jax.mgn.rollout.rollout``, set up by ``benchmarks.rollout_throughput.rollout_setup``);
- one solver trajectory of the ``--preset`` mesh (``benchmarks.solver_speed.timed_simulate``: a compile
  run, then the timed run).
Full size: ``--preset paper``, 15 x 128, 100 frames. ``--smoke``: preset tiny, 1 x 8, 3 frames, a
2-frame solver run, 256² matmul, and (when jax has not started yet) XLA's quick compile options
(:data:`SMOKE_XLA_FLAGS`: compilation is most of a smoke run's time, and its timings mean nothing).

Always returns something (issue 42): each part (``matmul``, ``mgn``, ``rollout``, ``solver``) runs in a process
of its own, started only while ``--budget_s`` (default 300 s, the whole check) has time left and killed when
it runs past it; each row is printed and the JSON (atomically rewritten) updated as soon as its part ends,
and a part that did not fit is recorded as ``{"skipped": "why"}``. (The parent process never touches the
device: on a GPU the parts would otherwise compete for its preallocated memory.) ``--parts`` picks and orders
them. Writes JSON where ``--json`` says (default without ``--smoke``: results/benchmarks/gpu_check.json) and
the table beside it (``--md``).
"""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

from benchmarks import common
from pcmgn_jax import cli
from pcmgn_jax.eval import bench
from pcmgn_jax.presets import PresetName

FULL = {"preset": "paper", "latent": 128, "layers": 15, "frames": 100, "solver_frames": 0, "repeats": 5,
        "scan": 3, "matmul_n": 0}
SMOKE = {"preset": "tiny", "latent": 8, "layers": 1, "frames": 3, "solver_frames": 2, "repeats": 2, "scan": 2,
         "matmul_n": 256}
PARTS = ("matmul", "mgn", "rollout", "solver")
MIN_PART_S = 10.0     # a part is not started with less of the budget left [s] (a process start and a compile)
SMOKE_XLA_FLAGS = "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"  # ~1/3 less CPU


@dataclass(frozen=True)
class GpuCheckArgs(common.Outputs):
    smoke: bool = False                  # the same code at small sizes (tests, CPU)
    preset: PresetName | None = None     # mesh preset of the graph, rollout and solver (None: paper; smoke: tiny)
    latent: int | None = None            # latent size (None: 128; smoke: 8)
    layers: int | None = None            # message-passing steps (None: 15; smoke: 1)
    frames: int | None = None            # rollout frames (None: 100; smoke: 3)
    solver_frames: int | None = None     # solver frames (0 = the scene's 100; None: 0; smoke: 2)
    repeats: int | None = None           # timed calls of each (None: 5; smoke: 2)
    scan: int | None = None              # train steps per dispatch of the lax.scan variant (None: 3; smoke: 2)
    matmul_n: int | None = None          # matmul size (0 = 8192 on an accelerator, 1024 on a CPU; None: 0; smoke: 256)
    budget_s: float = 300.0              # seconds for the whole check: a part that does not fit is skipped or cut
    parts: str = ",".join(PARTS)         # comma list of parts, in order (matmul, mgn, rollout, solver)
    part: str | None = None              # internal (a child process): run this part only
    part_out: str | None = None          # internal (a child process): its JSON


def _args(argv) -> GpuCheckArgs:
    """The flags, with the sizes not given taken from FULL (or SMOKE with --smoke)."""
    a = cli.parse(GpuCheckArgs, argv, description=__doc__, prog="python -m benchmarks.gpu_check")
    return dataclasses.replace(a, **{k: v for k, v in (SMOKE if a.smoke else FULL).items() if getattr(a, k) is None})


def device_info() -> dict:
    import jax
    d = jax.devices()[0]
    return {"backend": jax.default_backend(), "platform": d.platform, "kind": d.device_kind,
            "device_count": jax.device_count(),
            "matmul_precision": str(jax.config.jax_default_matmul_precision)}


def train_and_forward(a, n_nodes: int) -> dict:
    """Forward, train step (1 and ``a.scan`` per dispatch) on a crop of ~``n_nodes`` nodes of the preset's
    mesh (ball pressed into the glass, so contact edges are live), with the FLOPs of each."""
    from benchmarks.mgn_vs_torch import jax_results, prepare_jax

    g = bench.bench_graph(n_nodes, a.preset)
    gi = g["info"]
    fns, meta = prepare_jax(g, SimpleNamespace(latent=a.latent, layers=a.layers, mlp_layers=2, scan=a.scan))
    res = jax_results(bench.time_calls(fns, repeats=a.repeats, warmup=1), meta)
    flops = bench.mgn_flops(gi["n_nodes"], {"mesh": gi["n_mesh_edges"], "contact": gi["contact_capacity"]},
                             {"node": gi["node_feature_dim"], "mesh": g["mesh_features"].shape[1],
                              "contact": g["contact_features"].shape[1]},
                             latent=a.latent, mlp_layers=2, steps=a.layers)
    res.update(n_nodes=gi["n_nodes"], n_mesh_edges=gi["n_mesh_edges"], flops=flops,
               train_steps_per_s=1e3 / res["train_step_ms"], train_steps_per_s_scan=1e3 / res["train_step_scan_ms"])
    return res


def rollout_time(a) -> dict:
    """One ``a.frames`` rollout (lax.scan) of one design on the preset's ROI mesh, random parameters."""
    import jax

    from benchmarks.rollout_throughput import rollout_setup
    from pcmgn_jax.mgn.rollout import rollout

    s = rollout_setup(a.preset, latent=a.latent, layers=a.layers, n_designs=1)
    args = (s["params"], s["stats"], s["topology"], s["index"]) + tuple(s[k][0] for k in ("points", "u0", "v0", "vm0"))
    t0 = time.perf_counter()
    fn = rollout.lower(s["spec"], a.frames, *args).compile()
    compile_s = time.perf_counter() - t0
    t = bench.time_calls({"rollout": lambda: jax.block_until_ready(fn(*args))}, repeats=a.repeats, warmup=1)
    ms = t["rollout"]["median_ms"]
    return {"frames": a.frames, "s": ms / 1e3, "ms_per_frame": ms / a.frames, "compile_s": compile_s,
            "n_nodes": s["n_nodes"], "timing": t["rollout"]}


def solver_time(a) -> dict:
    """One solver trajectory of the preset's mesh (one design; compile run, then the timed run)."""
    from benchmarks.solver_speed import designs, timed_simulate
    from pcmgn_jax.scene import default_scene

    base = default_scene()
    return timed_simulate([base.with_design(*designs(1)[0])], a.preset, a.solver_frames or base.n_frames)


def run_part(a) -> dict:
    """The child's work: one part on the default device, with the device and machine blocks."""
    out: dict = {"device": device_info(), "machine": bench.machine_info()}
    if a.part == "matmul":
        n = a.matmul_n or (1024 if out["device"]["backend"] == "cpu" else 8192)
        out["result"] = {"n": n, "gflops": bench.matmul_gflops_jax(n, repeats=max(a.repeats, 3))}
    elif a.part == "rollout":
        out["result"] = rollout_time(a)
    elif a.part == "mgn":
        from benchmarks.rollout_throughput import rollout_setup
        n_nodes = rollout_setup(a.preset, latent=a.latent, layers=a.layers, n_designs=1)["n_nodes"]
        out["result"] = train_and_forward(a, n_nodes)                # the rollout's node count
    elif a.part == "solver":
        out["result"] = solver_time(a)
    else:
        raise ValueError(f"--part {a.part!r}: one of {PARTS}")
    return out


def _child(a, part: str, argv, timeout: float) -> tuple[dict | None, str]:
    """Run ``part`` in a process of its own within ``timeout`` [s]: (its output, '') or (None, why)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "part.json"
        cmd = [sys.executable, "-m", "benchmarks.gpu_check", *argv, "--part", part, "--part_out", str(out)]
        t0 = time.perf_counter()
        try:
            run = subprocess.run(cmd, cwd=Path(__file__).resolve().parents[1], capture_output=True, text=True,
                                 timeout=timeout)
        except subprocess.TimeoutExpired:
            return None, f"did not finish in the {timeout:.0f} s left of --budget_s={a.budget_s:g} (killed)"
        if run.returncode != 0 or not out.exists():
            tail = (run.stderr or run.stdout).strip().splitlines()[-3:]
            return None, f"failed (exit {run.returncode} after {time.perf_counter() - t0:.0f} s): " + " | ".join(tail)
        return json.loads(out.read_text()), ""


def _rows(result: dict, a) -> list[list]:
    """The table's rows for the parts measured so far (a skipped part: one row saying why)."""
    rows = []
    for part in a.parts.split(","):
        r = result.get(part)
        if r is None:
            continue
        if "skipped" in r:
            rows.append([part, "skipped: " + r["skipped"], "", "", ""])
        elif part == "matmul":
            rows.append(["dense matmul", f"{r['n']}² float32 jnp.dot", r["gflops"], "GFLOP/s", ""])
        elif part == "mgn":
            frac = lambda k: f"{100 * r[k + '_fraction_of_matmul']:.0f} %" if k + "_fraction_of_matmul" in r else ""  # noqa: E731
            rows += [["MGN forward", f"{r['n_nodes']} nodes, {a.layers} x {a.latent}", r["forward_ms"], "ms",
                      frac("forward")],
                     ["train step, 1 per dispatch", "model + MSE + Adam", r["train_steps_per_s"], "steps/s",
                      frac("train_step")],
                     [f"train step, {a.scan} per dispatch", "lax.scan", r["train_steps_per_s_scan"], "steps/s",
                      frac("train_step_scan")]]
        elif part == "rollout":
            rows.append(["MGN rollout", f"{r['frames']} frames, {r['n_nodes']} nodes (compile {r['compile_s']:.1f} s)",
                         r["s"], "s", ""])
        elif part == "solver":
            rows.append(["solver trajectory", (f"{a.preset} mesh, {r['n_frames']} frames x {r['n_sub_per_frame']} "
                                               f"substeps (compile {r['compile_s']:.1f} s)"), r["wall_s"], "s", ""])
    return rows


def _fractions(result: dict) -> None:
    """The MGN figures as fractions of the matmul rate, once both are measured."""
    mgn, mm = result.get("mgn") or {}, result.get("matmul") or {}
    if "gflops" not in mm or "flops" not in mgn:
        return
    for key, ms, fl in (("forward", mgn["forward_ms"], mgn["flops"]["forward"]),
                        ("train_step", mgn["train_step_ms"], mgn["flops"]["train_step_approx"]),
                        ("train_step_scan", mgn["train_step_scan_ms"], mgn["flops"]["train_step_approx"])):
        mgn[f"{key}_gflops"] = fl / (ms * 1e-3) / 1e9
        mgn[f"{key}_fraction_of_matmul"] = mgn[f"{key}_gflops"] / mm["gflops"]


def main(argv=None) -> dict:
    argv = cli.normalize_argv(GpuCheckArgs, sys.argv[1:] if argv is None else argv)   # underscore flag names
    a = _args(argv)
    if a.smoke and not _backend_started():          # XLA reads its flags when jax starts a backend (children inherit)
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {SMOKE_XLA_FLAGS}".strip()
    from pcmgn_jax.atomic import atomic_write_text
    if a.part is not None:                          # a child process: one part, its JSON to --part_out
        atomic_write_text(Path(a.part_out), json.dumps(common.clean(run_part(a)), allow_nan=False))
        return {}

    parts = a.parts.split(",")
    if not parts or set(parts) - set(PARTS):
        raise ValueError(f"--parts {a.parts!r}: a comma list of {', '.join(PARTS)}")
    t_start = time.perf_counter()
    cmd = cli.command_line("benchmarks.gpu_check", argv)
    result: dict = {"device": None, "machine": None,
                    "config": {**{k: getattr(a, k) for k in FULL}, "smoke": a.smoke, "mlp_layers": 2,
                               "budget_s": a.budget_s, "parts": parts, "command": cmd}}
    json_path = Path(a.json) if a.json else (None if a.smoke else common.RESULTS / "gpu_check.json")
    md_path = None if json_path is None else (Path(a.md) if a.md else json_path.with_suffix(".md"))

    def table() -> str:
        dev = result["device"] or {"platform": "?", "kind": "?", "device_count": "?"}
        jax_v = (result["machine"] or {}).get("jax", "?")
        rows = _rows(result, a) + [["whole check", f"budget {a.budget_s:g} s", result.get("total_s", 0.0), "s", ""]]
        return (f"## GPU check — {dev['platform']} {dev['kind']} (jax {jax_v}, {dev['device_count']} device(s))\n\n"
                f"`{cmd}`\n\n" + common.md_table(["what", "size", "value", "unit", "of the matmul rate"], rows))

    def save() -> None:
        result["total_s"] = time.perf_counter() - t_start
        if json_path is None:
            return
        json_path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(json_path, json.dumps(common.clean(result), indent=1, allow_nan=False) + "\n")
        atomic_write_text(md_path, table())

    child_argv = _drop_values(argv, ("--json", "--md", "--budget_s", "--parts"))
    for part in parts:
        left = a.budget_s - (time.perf_counter() - t_start)
        if left < MIN_PART_S:
            result[part] = {"skipped": f"not started: {max(left, 0):.0f} s of --budget_s={a.budget_s:g} left "
                                       f"(a part needs at least {MIN_PART_S:g} s)"}
        else:
            t0 = time.perf_counter()
            out, why = _child(a, part, child_argv, left)
            if out is None:
                result[part] = {"skipped": why}
            else:
                result[part] = {**out["result"], "part_wall_s": time.perf_counter() - t0}
                result["device"] = result["device"] or out["device"]
                result["machine"] = result["machine"] or out["machine"]
                _fractions(result)
        for row in _rows({part: result[part], "matmul": result.get("matmul")},
                         SimpleNamespace(**{**vars(a), "parts": part})):
            print(" | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in row), flush=True)
        save()
    save()
    md = table()
    print(md)
    if json_path is not None:
        print(f"wrote {json_path} and {md_path}")
    return result


def _backend_started() -> bool:
    """Whether JAX has started a backend in this process (XLA has read ``XLA_FLAGS``): importing jax, as the
    command line does (pcmgn_jax.cli), does not."""
    if "jax" not in sys.modules:
        return False
    from jax._src import xla_bridge  # no public form of this question
    return xla_bridge.backends_are_initialized()


def _drop_values(argv, flags) -> list[str]:
    """``argv`` without ``flags`` (``--flag value`` or ``--flag=value``)."""
    out, skip = [], False
    for x in argv:
        if skip:
            skip = False
            continue
        name = x.split("=", 1)[0]
        if name in flags:
            skip = "=" not in x
            continue
        out.append(x)
    return out


if __name__ == "__main__":
    common.run(main)
