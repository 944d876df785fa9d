"""Solver throughput against the number of designs per compiled call (issue 42).

    python -m benchmarks.solver_throughput [--presets cpu,paper] [--max_batch 256] [--frames 10]
        [--budget_s 600] [--json PATH]

For each mesh preset (the default scene's full mesh) and batch size b = 1, 2, 4, ... ``--max_batch``: one
compiled call of the built-in solver (:func:`pcmgn_jax.sim.solver._run`) integrating b designs for
``--frames`` output frames. The designs are 8 distinct OCA1/OCA2 thicknesses (50-150 µm), prepared once
on the host and repeated to fill the batch (the cost of a call does not depend on the values; the 8 share
one stable step, so every row integrates the same substeps). Per row: the compile seconds (AOT
``lower().compile()``, from the persistent cache when warm), the median seconds of ``--repeats`` timed calls
(device time: ``block_until_ready``, no host transfer), designs per second at the measured frames, the same
for a full trajectory of the scene's frames **extrapolated** linearly (explicit dynamics: a constant cost
per substep; flagged ``extrapolated_to_frames``), and the speed-up over b = 1 of the same preset. The host
preparation per design (mesh, element matrices, stable-step eigenvalues; ``prepare_s_per_design``) is
measured once per preset and reported beside, not included.

Each row is printed and written to the JSON (atomically) as soon as it is measured; ``--budget_s`` bounds
the whole run: a row is not started when the time left is less than 1.5 times what the previous row of the
preset took (compile included: on an H200 each row compiles for 15-24 s, whatever its batch), and the skipped
rows are listed with the reason. ``--sizes`` gives the batch sizes explicitly and in order (e.g. ``1,256,16``:
the largest right after the single design).
"""
from __future__ import annotations

import json
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks import common
from pcmgn_jax import cli
from pcmgn_jax.eval import bench


@dataclass(frozen=True)
class SolverThroughputArgs:
    presets: str = "cpu,paper"   # comma list of mesh presets
    max_batch: int = 256         # largest batch (powers of two from 1)
    sizes: str = ""              # comma list of batch sizes (overrides --max_batch)
    frames: int = 10             # output frames integrated per call
    repeats: int = 2             # timed calls per row (median)
    budget_s: float = 600.0      # seconds for the whole run
    json: str | None = None      # result JSON (default results/benchmarks/solver_throughput.json)


def sizes(a) -> list[int]:
    if a.sizes:
        out = [int(x) for x in a.sizes.split(",") if x.strip()]
    else:
        out = [1 << k for k in range(0, max(0, int(a.max_batch)).bit_length()) if 1 << k <= a.max_batch]
    if not out or min(out) < 1:
        raise ValueError(f"batch sizes must be >= 1, got {out}")
    return out


def setup(preset: str, n_frames: int):
    """(Calls of 8 prepared designs, host seconds of preparation per design, the scene's frames)."""
    from benchmarks.solver_speed import designs
    from pcmgn_jax.scene import default_scene
    from pcmgn_jax.sim import solver

    base = default_scene()
    scenes = [base.with_design(*d) for d in designs(8)]
    t0 = time.perf_counter()
    prep = solver.prepare(scenes, preset)
    prep_s = (time.perf_counter() - t0) / len(scenes)
    calls = solver.Calls(scenes, prep, settings=solver.DEFAULT_SETTINGS, n_frames=n_frames,
                         output_dt=base.output_dt)
    return calls, prep_s, base.n_frames


def measure(calls, b: int, repeats: int) -> dict:
    """Compile (AOT) and time one call of ``b`` designs (median of ``repeats``)."""
    import jax

    from pcmgn_jax.sim import solver

    args, static = calls.inputs(np.arange(b) % calls.prep.points.shape[0])
    t0 = time.perf_counter()
    compiled = solver._run.lower(*args, **static).compile()
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        out = jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - t0)
    finite = bool(np.isfinite(np.asarray(out[3])).all())      # the energies of every design
    return {"compile_s": compile_s, "call_s": statistics.median(times), "call_s_all": times, "finite": finite}


def main(argv=None) -> dict:
    a = cli.parse(SolverThroughputArgs, argv, description=__doc__, prog="python -m benchmarks.solver_throughput")
    import jax

    from pcmgn_jax.atomic import atomic_write_text

    t_start = time.perf_counter()
    path = Path(a.json) if a.json else common.RESULTS / "solver_throughput.json"
    dev = jax.devices()[0]
    result = {"device": {"backend": jax.default_backend(), "kind": dev.device_kind, "platform": dev.platform},
              "config": {"presets": a.presets.split(","), "sizes": sizes(a), "frames": a.frames,
                         "repeats": a.repeats, "budget_s": a.budget_s,
                         "command": cli.command_line("benchmarks.solver_throughput", argv)},
              "machine": bench.machine_info(), "rows": [], "skipped": []}

    def save():
        result["total_s"] = time.perf_counter() - t_start
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps(common.clean(result), indent=1, allow_nan=False) + "\n")

    print("preset | batch | nodes | substeps/call | compile s | call s | designs/s | designs/s (full, extrap.) "
          "| speed-up vs 1", flush=True)
    for preset in a.presets.split(","):
        left = a.budget_s - (time.perf_counter() - t_start)
        if left <= 0:
            result["skipped"].append({"preset": preset, "why": "budget spent before the preset's preparation"})
            save()
            continue
        calls, prep_s, full_frames = setup(preset, a.frames)
        single, last_s = None, 0.0
        for b in sizes(a):
            left = a.budget_s - (time.perf_counter() - t_start)
            if left < 1.5 * last_s or left <= 0:
                result["skipped"].append({"preset": preset, "batch": b, "why": (
                    f"{left:.0f} s of --budget_s={a.budget_s:g} left, the previous row took {last_s:.0f} s")})
                print(f"{preset} | {b} | skipped: {result['skipped'][-1]['why']}", flush=True)
                save()
                continue
            t0 = time.perf_counter()
            m = measure(calls, b, a.repeats)
            last_s = time.perf_counter() - t0
            per_s = b / m["call_s"]
            single = per_s if single is None and b == 1 else single
            row = {"preset": preset, "batch": b, "n_nodes": int(calls.prep.mesh.n_nodes), "frames": a.frames,
                   "n_sub_per_frame": calls.n_sub, "substeps_per_call": a.frames * calls.n_sub, **m,
                   "designs_per_s": per_s, "extrapolated_to_frames": full_frames,
                   "designs_per_s_full_trajectory": per_s * a.frames / full_frames,
                   "speedup_vs_batch_1": None if single is None else per_s / single,
                   "prepare_s_per_design": prep_s, "row_wall_s": last_s}
            result["rows"].append(row)
            save()
            print(f"{preset} | {b} | {row['n_nodes']} | {row['substeps_per_call']} | {m['compile_s']:.2f} | "
                  f"{m['call_s']:.4g} | {per_s:.4g} | {row['designs_per_s_full_trajectory']:.4g} | "
                  + ("" if row["speedup_vs_batch_1"] is None else f"{row['speedup_vs_batch_1']:.1f}x"), flush=True)
    save()
    print(f"wrote {path} ({len(result['rows'])} rows, {len(result['skipped'])} skipped, "
          f"{result['total_s']:.0f} s)")
    return result


if __name__ == "__main__":
    common.run(main)
