"""Speed of the built-in explicit FE solver: substeps/s and wall time per default trajectory.

    python -m benchmarks.solver_speed [--presets cpu,paper] [--batch 8] [--frames 100]
        [--probe_frames 5] [--budget 120] [--designs_per_call 0] [--json PATH] [--md PATH]

For each mesh preset: the full (un-cropped) mesh of the default scene, designs = OCA1/OCA2
thicknesses spread over 50-150 µm. Each configuration runs ``solver.simulate`` twice with the
same shapes; the first call compiles, the second is the timed one (``RunResult.wall_time_s``,
device time of the jitted scan, excluding meshing / element matrices / the eigenvalue estimate,
which are reported separately as ``prepare_s``).

A short ``--probe_frames`` run comes first; when the full ``--frames`` trajectory is predicted to
take longer than ``--budget`` seconds, the full run is skipped and its wall time is EXTRAPOLATED
linearly from the probe (explicit dynamics: constant cost per substep), flagged ``extrapolated``.
Single design and a batch of ``--batch`` designs -> throughput ratio. ``--designs_per_call``
is ``SolverSettings.designs_per_call`` (0: the solver's default, one design at a time on CPU;
``--designs_per_call 8`` integrates the batch of 8 in one vectorised call).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from benchmarks import common
from pcmgn_jax import cli
from pcmgn_jax.eval import bench


@dataclass(frozen=True)
class SolverSpeedArgs(common.Outputs):
    presets: str = "cpu,paper"   # comma list of mesh presets
    batch: int = 8               # designs of the batched run
    frames: int = 0              # trajectory frames (0 = the scene default, 100)
    probe_frames: int = 5        # frames of the short probe run
    budget: float = 120.0        # max predicted seconds of one full timed run; longer runs are extrapolated
    designs_per_call: int = 0    # SolverSettings.designs_per_call (0 = the solver's default)
    elements: str = "q4i"        # comma list of Q4 elements (pcmgn_jax.sim.fem.Q4_ELEMENTS); several: a ratio line


def designs(n: int) -> list[tuple[float, float]]:
    rng = np.random.default_rng(0)
    return [tuple(x) for x in rng.uniform(50e-6, 150e-6, size=(n, 2))]


def timed_simulate(scenes, preset, n_frames: int, designs_per_call: int = 0, element: str = "q4i") -> dict:
    """Compile run + timed run; returns timing dict for the batch."""
    from pcmgn_jax.sim import solver
    settings = solver.SolverSettings(designs_per_call=designs_per_call, element=element)
    t0 = time.perf_counter()
    first = solver.simulate(scenes, preset, n_frames=n_frames, settings=settings)
    first_total = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = solver.simulate(scenes, preset, n_frames=n_frames, settings=settings)
    total = time.perf_counter() - t0
    b = len(scenes)
    sub = n_frames * res.n_sub
    mesh = res.prepared.mesh
    return dict(batch=b, n_frames=n_frames, n_sub_per_frame=res.n_sub, dt_s=res.dt, substeps=sub,
                wall_s=res.wall_time_s, prepare_s=total - res.wall_time_s,
                compile_s=max(0.0, first.wall_time_s - res.wall_time_s), first_call_total_s=first_total,
                substeps_per_s=sub / res.wall_time_s, design_substeps_per_s=b * sub / res.wall_time_s,
                wall_s_per_design=res.wall_time_s / b, n_nodes=int(mesh.n_nodes),
                n_cells=int(mesh.cells.shape[0]), max_energy_error=float(np.max(res.energy_error)))


def main(argv=None) -> dict:
    a = cli.parse(SolverSpeedArgs, argv, description=__doc__, prog="python -m benchmarks.solver_speed")
    from pcmgn_jax.scene import default_scene

    base = default_scene()
    frames = a.frames or base.n_frames
    presets = [p for p in a.presets.split(",") if p]
    elements = [e for e in a.elements.split(",") if e]
    out, rows = {}, []
    t_start = time.perf_counter()
    for preset, element in [(p, e) for p in presets for e in elements]:
        key = preset if len(elements) == 1 else f"{preset}:{element}"
        res = {}
        for b in (1, a.batch):
            scenes = [base.with_design(*d) for d in designs(b)]
            probe = timed_simulate(scenes, preset, a.probe_frames, a.designs_per_call, element)
            predicted = probe["wall_s"] * frames / a.probe_frames
            entry = dict(probe=probe, predicted_full_wall_s=predicted)
            if predicted <= a.budget and frames != a.probe_frames:
                full = timed_simulate(scenes, preset, frames, a.designs_per_call, element)
                entry.update(full=full, wall_s_trajectory=full["wall_s"], extrapolated=False,
                             substeps_per_s=full["substeps_per_s"])
            else:
                entry.update(wall_s_trajectory=predicted, extrapolated=frames != a.probe_frames,
                             substeps_per_s=probe["substeps_per_s"])
            entry["wall_s_per_design"] = entry["wall_s_trajectory"] / b
            entry["designs_per_s"] = b / entry["wall_s_trajectory"]
            res[str(b)] = entry
            info = entry.get("full", probe)
            rows.append([key, info["n_nodes"], b, info["n_sub_per_frame"], f"{info['dt_s']:.3g}",
                         entry["substeps_per_s"], entry["wall_s_trajectory"], entry["wall_s_per_design"],
                         "extrapolated" if entry["extrapolated"] else "measured"])
        if "1" in res and str(a.batch) in res:
            res["batch_throughput_ratio"] = res["1"]["wall_s_per_design"] / res[str(a.batch)]["wall_s_per_design"]
        out[key] = res
    config = dict(presets=presets, elements=elements, batch=a.batch, designs_per_call=a.designs_per_call, frames=frames,
                  probe_frames=a.probe_frames, budget_s=a.budget,
                  scene="default_scene (axisymmetric, 8 mm half width, full mesh, 6 layers)",
                  command=cli.command_line("benchmarks.solver_speed", argv),
                  total_benchmark_s=time.perf_counter() - t_start)
    result = dict(solver=out, config=config, machine=bench.machine_info())
    md = [f"## Explicit FE solver speed — {frames}-frame default trajectory\n",
          f"`{config['command']}` — {result['machine']['cpu']}, {result['machine']['cores_usable']} cores, "
          f"jax {result['machine']['jax']}\n\n",
          common.md_table(["preset", "full-mesh nodes", "designs", "substeps/frame", "dt [s]",
                           "substeps/s (per call)", "wall s / trajectory call", "wall s / design", "how"], rows)]
    for p, r in out.items():
        if "batch_throughput_ratio" in r:
            md.append(f"\n{p}: batch of {a.batch} gives {r['batch_throughput_ratio']:.2f}x the per-design "
                      f"throughput of single runs.")
    for p in presets if len(elements) > 1 else ():
        cost = [out[f"{p}:{e}"]["1"]["wall_s_per_design"] for e in elements]
        md.append(f"\n{p}: one design costs " + ", ".join(f"{e} {c / cost[-1]:.2f}x" for e, c in zip(elements, cost))
                  + f" of {elements[-1]}'s (same run).")
    md.append("\n")
    jp, mp = common.default_paths("solver_speed", a.json, a.md)
    common.write_outputs(result, jp, mp, "".join(md))
    return result


if __name__ == "__main__":
    common.run(main)
