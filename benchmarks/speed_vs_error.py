"""Surrogate against solver: wall time per design vs error on held-out designs (Pareto plot).

    python -m benchmarks.speed_vs_error --runs runs/l32s5,runs/l64s8,runs/l128s15 \\
        --solver_presets cpu,cpu@1.5,cpu@2,tiny [--baselines nearest,poly2,rbf] [--n_test 6] [--json PATH] ...

Ground truth: the held-out (test split) trajectories of the runs' dataset, i.e. the solver at the
training mesh (all runs must share one dataset). Points:

- surrogates: each run directory (trained with ``python -m experiments.train``), best checkpoint,
  batched ``rollout_checked`` over the test designs (compiled before timing). Cost per design =
  rollout wall time / n_designs + building the design's ROI mesh (``mesh_build_s``).
- baselines (``--baselines``): the design-space regressions of :mod:`pcmgn_jax.surrogates`, fitted
  on the first ``n_train`` training trajectories (the run's), cost per design = prediction wall time.
- solvers: each mesh preset (``tiny|cpu|paper``, or ``PRESET@F`` = PRESET with element sizes x F and
  through-thickness element counts / F) run on the same designs with ``solver.simulate`` (batched,
  second call timed, so compilation is excluded). Cost per design = (scan wall time + host prepare:
  meshing, element matrices, stable-step eigenvalue) / n_designs. Fields on another mesh are
  interpolated to the reference ROI nodes per part (piecewise linear on a Delaunay triangulation of
  the part's nodes, nearest node outside it). The training-mesh preset reproduces the ground truth
  (error ~0: a check of the pipeline) and gives the reference cost.

Errors as pcmgn_jax.eval.evaluate: position MAE [µm] and von Mises MAE [MPa] over frames 1..T, ROI nodes
(and components), test designs. Output: table, JSON, a two-panel speed-vs-error PNG with the Pareto
front, and for every surrogate the fastest solver at least as accurate (the speed-up it buys).
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from benchmarks import common
from pcmgn_jax import cli
from pcmgn_jax.eval import bench


@dataclass(frozen=True)
class SpeedVsErrorArgs(common.Outputs):
    runs: str = ""               # comma-separated run directories
    solver_presets: str = ""     # comma-separated mesh presets, e.g. cpu,cpu@2,tiny
    dataset: str = ""            # dataset dir (default: the first run's)
    n_test: int = 0              # held-out designs (0 = the run config's n_test)
    which: Literal["best", "periodic"] = "best"   # checkpoint
    # comma-separated design-space baselines fitted on the training split (none, nearest, poly2, rbf:
    # pcmgn_jax.surrogates), timed like the surrogates
    baselines: str = ""
    n_train: int = 0             # training designs the baselines fit (0 = the run config's n_train)
    png: str | None = None       # the plot (default: the JSON's path with .png)


# ---- errors ---------------------------------------------------------------------------------------

def errors(pred_u, pred_vm, test_trajs) -> dict:
    """pred_u (B,T,N,2) [m], pred_vm (B,T,N) [Pa] on the test trajectories' nodes (pcmgn_jax.metrics)."""
    from pcmgn_jax.metrics import position_errors_um, stress_errors_mpa
    tu = np.stack([np.asarray(t.displacement, np.float64) for t in test_trajs])
    ts = np.stack([np.asarray(t.von_mises, np.float64) for t in test_trajs])
    pos = position_errors_um(pred_u, tu)
    st = stress_errors_mpa(pred_vm, ts)
    return dict(position_mae_um=float(pos.mean()), position_max_um=float(pos.max()),
                stress_mae_mpa=float(st.mean()), stress_max_mpa=float(st.max()),
                finite=bool(np.isfinite(pos).all() and np.isfinite(st).all()))


# ---- surrogates ---------------------------------------------------------------------------------

def surrogate_point(workdir, test_trajs, *, which: str = "best", label: str | None = None) -> dict:
    """The trained MGN of ``workdir`` through the evaluation's surrogate (batched rollouts, compiled
    before timing); a single-design rollout timed separately."""
    import jax

    from pcmgn_jax.surrogates.mgn import MGNSurrogate

    workdir = Path(workdir)
    ref = test_trajs[0]
    mgn = MGNSurrogate(workdir, ref, which=which, batch=len(test_trajs))
    pu, pvm = mgn.rollout_trajectories(test_trajs)
    wall = mgn.rollout_seconds
    one = MGNSurrogate(workdir, ref, which=which, batch=1)
    one.rollout_trajectories(test_trajs[:1])
    wall1 = one.rollout_seconds
    cfg = mgn.sim.config
    mesh_s = _mesh_build_s(ref)
    n_params = int(sum(x.size for x in jax.tree.leaves(mgn.sim.params)))
    err = errors(pu, pvm, test_trajs)
    per = wall / len(test_trajs)
    return dict(kind="surrogate", label=label or f"MGN {cfg.latent_size}x{cfg.message_passing_steps} "
                f"({workdir.name})", workdir=str(workdir), latent=cfg.latent_size,
                steps=cfg.message_passing_steps, lambda_pen=cfg.lambda_pen, n_params=n_params,
                rollout_s_batched=wall, rollout_s_single=wall1, mesh_build_s=mesh_s,
                seconds_per_design=per + mesh_s, seconds_single_design=wall1 + mesh_s,
                n_designs=len(test_trajs), **err)


def baseline_point(kind: str, train_trajs, test_trajs) -> dict:
    """A design-space baseline (:class:`pcmgn_jax.surrogates.regression.FieldRegression`) fitted on
    ``train_trajs``, predicting the test designs' fields on the shared mesh; cost per design = its
    prediction wall time (no mesh needed: it predicts the reference nodes' fields directly)."""
    from pcmgn_jax.surrogates.inputs import design_of
    from pcmgn_jax.surrogates.regression import FieldRegression
    model = FieldRegression(kind, train_trajs)
    designs = np.stack([design_of(t) for t in test_trajs])
    model.predict(designs[:1])  # warm-up (lazy imports, first call)
    t0 = time.perf_counter()
    pu, pvm = model.predict(designs)
    wall = time.perf_counter() - t0
    err = errors(pu, pvm, test_trajs)
    return dict(kind="baseline", label=f"baseline {kind}", fit_seconds=model.fit_seconds,
                seconds_per_design=wall / len(test_trajs), n_designs=len(test_trajs), **err)


def _mesh_build_s(ref) -> float:
    """Host time to build one design's ROI mesh (the surrogate needs its node positions)."""
    meta = ref.meta
    if meta.get("source") != "solver" or "solver" not in meta:
        return 0.0
    from pcmgn_jax.scene import Scene
    from pcmgn_jax.sim.mesh import build_mesh, roi
    spec = _spec_from_meta(meta)
    scene = Scene.from_dict(meta["scene"])
    t0 = time.perf_counter()
    roi(build_mesh(scene, spec), spec)
    return time.perf_counter() - t0


# ---- solvers --------------------------------------------------------------------------------------

def solver_spec(name: str):
    """'cpu' -> MESH_PRESETS['cpu']; 'cpu@2' -> element sizes x2, through-thickness counts / 2."""
    from pcmgn_jax.sim.mesh import mesh_spec, with_spec
    if "@" not in name:
        return mesh_spec(name)
    base, f = name.split("@", 1)
    f = float(f)
    s = mesh_spec(base)
    return with_spec(base, h_contact=s.h_contact * f, h_layer=s.h_layer * f,
                     layer_elems={k: max(1, int(math.ceil(v / f))) for k, v in s.layer_elems.items()})


def _spec_from_meta(meta):
    from pcmgn_jax.sim.mesh import MeshSpec
    d = dict(meta["solver"]["mesh_spec"])
    return MeshSpec(**d)


def transfer(src_points, src_cells, src_cell_part, field, dst_points, dst_node_part) -> np.ndarray:
    """Interpolate a nodal ``field`` (T, Ns, d) from a source mesh to destination nodes, per part."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator
    T = field.shape[0]
    d = field.shape[2] if field.ndim == 3 else 1
    f = np.asarray(field, np.float64).reshape(T, field.shape[1], d)
    out = np.full((T, dst_points.shape[0], d), np.nan)
    for part in np.unique(dst_node_part):
        src = np.unique(src_cells[src_cell_part == part])
        dst = np.flatnonzero(dst_node_part == part)
        if src.size == 0 or dst.size == 0:
            continue
        vals = f[:, src].transpose(1, 0, 2).reshape(src.size, T * d)
        pts = src_points[src]
        scale = pts.std(0) + 1e-30   # isotropic scaling keeps thin layers well-conditioned for Qhull
        try:
            lin = LinearNDInterpolator(pts / scale, vals)(dst_points[dst] / scale)
        except Exception:  # noqa: BLE001 -- degenerate (e.g. collinear) point sets
            lin = np.full((dst.size, T * d), np.nan)
        bad = ~np.isfinite(lin).all(axis=1)
        if bad.any():
            lin[bad] = NearestNDInterpolator(pts / scale, vals)(dst_points[dst][bad] / scale)
        out[:, dst] = lin.reshape(dst.size, T, d).transpose(1, 0, 2)
    return out if field.ndim == 3 else out[..., 0]


def solver_point(preset_name: str, test_trajs, *, label: str | None = None) -> dict:
    from pcmgn_jax.scene import Scene
    from pcmgn_jax.sim import solver
    from pcmgn_jax.sim.mesh import roi

    spec = solver_spec(preset_name)
    scenes = [Scene.from_dict(t.meta["scene"]) for t in test_trajs]
    n_frames = test_trajs[0].n_frames - 1
    solver.simulate(scenes, spec, n_frames=n_frames)                # compile
    t0 = time.perf_counter()
    res = solver.simulate(scenes, spec, n_frames=n_frames)
    total = time.perf_counter() - t0
    ref_meta = test_trajs[0].meta
    same_mesh = "solver" in ref_meta and dataclasses.asdict(_spec_from_meta(ref_meta)) == \
        {**dataclasses.asdict(spec), "layer_elems": dict(spec.layer_elems)}
    pred_u, pred_vm = [], []
    if same_mesh:
        sub, node_map = roi(res.prepared.mesh, spec)
        for i in range(len(scenes)):
            pred_u.append(res.u[i][:, node_map])
            pred_vm.append(res.von_mises[i][:, node_map])
    else:
        m = res.prepared.mesh
        for i, t in enumerate(test_trajs):
            pts = res.prepared.points[i]
            pred_u.append(transfer(pts, m.cells, m.cell_part, res.u[i], np.asarray(t.points), t.node_part))
            pred_vm.append(transfer(pts, m.cells, m.cell_part, res.von_mises[i], np.asarray(t.points),
                                    t.node_part))
    err = errors(np.stack(pred_u), np.stack(pred_vm), test_trajs)
    b = len(scenes)
    return dict(kind="solver", label=label or f"solver {preset_name}", preset=preset_name,
                same_mesh_as_reference=bool(same_mesh), n_nodes=int(res.prepared.mesh.n_nodes),
                n_sub_per_frame=int(res.n_sub), dt_s=float(res.dt), scan_s_batched=res.wall_time_s,
                prepare_s_batched=total - res.wall_time_s, seconds_per_design=total / b,
                seconds_scan_per_design=res.wall_time_s / b, n_designs=b, **err)


# ---- analysis and plot ---------------------------------------------------------------------------

def pareto(points, err_key: str = "position_mae_um") -> list[int]:
    """Indices of the points on the (time, error) Pareto front, fastest first."""
    order = sorted(range(len(points)), key=lambda i: (points[i]["seconds_per_design"], points[i][err_key]))
    front, best = [], math.inf
    for i in order:
        if points[i][err_key] < best:
            front.append(i)
            best = points[i][err_key]
    return front


def verdicts(points, err_key: str = "position_mae_um") -> list[dict]:
    """For each surrogate: the fastest solver at least as accurate, and the speed-up over it."""
    solvers = [p for p in points if p["kind"] == "solver"]
    out = []
    for s in (p for p in points if p["kind"] == "surrogate"):
        ok = [q for q in solvers if q[err_key] <= s[err_key]]
        dominated_by = [q["label"] for q in solvers
                        if q["seconds_per_design"] <= s["seconds_per_design"] and q[err_key] <= s[err_key]]
        v = dict(surrogate=s["label"], error=s[err_key], seconds_per_design=s["seconds_per_design"],
                 dominated_by=dominated_by)
        if ok:
            q = min(ok, key=lambda q: q["seconds_per_design"])
            v.update(fastest_solver_as_accurate=q["label"], solver_seconds=q["seconds_per_design"],
                     speedup=q["seconds_per_design"] / s["seconds_per_design"])
        out.append(v)
    return out


def plot(points, path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, key, name in ((axes[0], "position_mae_um", "position MAE [µm]"),
                          (axes[1], "stress_mae_mpa", "von Mises MAE [MPa]")):
        pos = [p[key] for p in points if p[key] > 0]
        floor = (min(pos) / 3) if pos else 1e-3
        y = lambda p: max(p[key], floor)  # noqa: E731
        for kind, mk, col in (("solver", "s", "tab:blue"), ("surrogate", "o", "tab:red"),
                              ("baseline", "^", "tab:green")):
            sel = [p for p in points if p["kind"] == kind]
            ax.scatter([p["seconds_per_design"] for p in sel], [y(p) for p in sel], marker=mk, c=col,
                       label=kind, zorder=3)
            for p in sel:
                tag = p["label"] + (" (= reference)" if p[key] <= 0 or p.get("same_mesh_as_reference") else "")
                ax.annotate(tag, (p["seconds_per_design"], y(p)), fontsize=7, xytext=(4, 3),
                            textcoords="offset points")
        fr = pareto(points, key)
        ax.plot([points[i]["seconds_per_design"] for i in fr], [y(points[i]) for i in fr], "k--", lw=0.8,
                label="Pareto front", zorder=2)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time per design [s]")
        ax.set_ylabel(name)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("Speed vs error on held-out designs (errors against the training-mesh solver)")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130)
    plt.close(fig)


def report(points, *, command: str, json_path, md_path, png_path, extra: dict | None = None) -> dict:
    if not points:
        raise ValueError("speed_vs_error: no points (give --runs and/or --solver_presets)")
    plot(points, png_path)
    v_pos = verdicts(points, "position_mae_um")
    v_st = verdicts(points, "stress_mae_mpa")
    result = dict(points=points, pareto_position=[points[i]["label"] for i in pareto(points, "position_mae_um")],
                  pareto_stress=[points[i]["label"] for i in pareto(points, "stress_mae_mpa")],
                  verdicts_position=v_pos, verdicts_stress=v_st, png=str(png_path),
                  config=dict(command=command, **(extra or {})), machine=bench.machine_info())
    rows = [[p["label"], p["kind"], p["seconds_per_design"], p["position_mae_um"], p["stress_mae_mpa"],
             "yes" if p["label"] in result["pareto_position"] else ""] for p in points]
    md = [f"## Speed vs error — surrogates against the solver ({points[0]['n_designs']} held-out designs)\n",
          f"`{command}` — {result['machine']['cpu']}, {result['machine']['cores_usable']} cores\n\n",
          common.md_table(["model", "kind", "s / design", "position MAE µm", "von Mises MAE MPa",
                           "on position Pareto front"], rows), "\n"]
    for v in v_pos:
        if "speedup" in v:
            md.append(f"- {v['surrogate']}: the fastest solver at least as accurate in position is "
                      f"{v['fastest_solver_as_accurate']} ({v['solver_seconds']:.3g} s/design) -> surrogate "
                      f"{v['speedup']:.3g}x {'faster' if v['speedup'] >= 1 else 'slower'}"
                      + (f"; dominated by {', '.join(v['dominated_by'])}" if v["dominated_by"] else "") + ".\n")
        else:
            md.append(f"- {v['surrogate']}: more accurate than every solver point measured.\n")
    md.append(f"\n![speed vs error]({Path(png_path).name})\n")
    common.write_outputs(result, Path(json_path), Path(md_path), "".join(md))
    return result


def main(argv=None) -> dict:
    a = cli.parse(SpeedVsErrorArgs, argv, description=__doc__, prog="python -m benchmarks.speed_vs_error")
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.data.cache import load_split

    runs = [r for r in a.runs.split(",") if r]
    presets = [p for p in a.solver_presets.split(",") if p]
    if not runs and not a.dataset:
        raise SystemExit("give --runs (and/or --dataset with --solver_presets)")
    cfgs = [TrainConfig.load(Path(r) / "config.json") for r in runs]
    dataset = a.dataset or cfgs[0].resolved_dataset_dir
    for r, c in zip(runs, cfgs):
        if not a.dataset and c.resolved_dataset_dir != dataset:
            raise SystemExit(f"run {r} was trained on {c.resolved_dataset_dir}, not {dataset}; one dataset only")
    n_test = a.n_test or (cfgs[0].n_test if cfgs else 6)
    test = load_split(dataset, "test")[:n_test]
    if not test:
        raise SystemExit(f"{dataset}/test holds no trajectories")
    points = [surrogate_point(r, test, which=a.which) for r in runs]
    kinds = [k for k in a.baselines.split(",") if k]
    if kinds:
        n_train = a.n_train or (cfgs[0].n_train if cfgs else 12)
        train = load_split(dataset, "train")[:n_train]
        points += [baseline_point(k, train, test) for k in kinds]
    points += [solver_point(p, test) for p in presets]
    jp, mp = common.default_paths("speed_vs_error", a.json, a.md)
    png = Path(a.png) if a.png else jp.with_suffix(".png")
    return report(points, command=cli.command_line("benchmarks.speed_vs_error", argv), json_path=jp, md_path=mp,
                  png_path=png,
                  extra=dict(dataset=str(dataset), n_test=len(test), runs=runs, solver_presets=presets))


if __name__ == "__main__":
    common.run(main)
