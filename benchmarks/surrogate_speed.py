"""The surrogate against the solver it learned from, in one run: seconds per design and the errors.

    python -m benchmarks.surrogate_speed --preset cpu [--workdir runs/cpu] [--json F] [--md F]
    python -m benchmarks.surrogate_speed --preset paper [--workdir RUN]   # no trained paper run: timing only

With a trained run (``--workdir``, default ``runs/<preset>``) the MGN rolls out the run's test designs
through the evaluation's surrogate (:class:`pcmgn_jax.surrogates.mgn.MGNSurrogate`: padded disjoint
unions of ``--batch`` designs, every frame of every node decoded) and is scored on them in the same run:
position MAE [µm], von Mises MAE [MPa] (:mod:`pcmgn_jax.metrics`) and the OLED objective's (section
area mean) relative error [%] (:func:`pcmgn_jax.eval.baselines.objective_scores`). Without one (the
``paper`` preset is a GPU job nobody has run), the model is the preset's size with RANDOM parameters
(shapes, not values, set the cost) and the errors are null.

Timings are warm: every path runs once untimed (compilation; its time is reported apart), then the
median of ``--repeats`` runs. Per design, MGN = rollout wall time / designs + placing the design's nodes
(host: the OCA box's affine design map, as the optimiser does; a family scene builds its ROI mesh); solver = the batched
``solver.simulate`` of the same designs (host prepare + scan) / designs. ``ratio`` = solver / MGN. The same network with
the ball state as a node input (processor every frame, the formulation before ``processor='per_design'``) is timed
beside it when the run is per-design: ``mgn_per_frame_s_per_design`` (same sizes; timing only, its outputs are not the
trained model's).
"""
from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from benchmarks import common
from pcmgn_jax import cli
from pcmgn_jax.eval import bench
from pcmgn_jax.presets import PresetName


@dataclass(frozen=True)
class SurrogateSpeedArgs(common.Outputs):
    preset: PresetName = "cpu"   # the solver preset (and the run's)
    workdir: str = ""            # trained run (default runs/<preset>; missing -> random parameters)
    n_test: int = 0              # test designs (0 = the run's n_test; 8 without a run)
    batch: int = 8               # designs per MGN call (disjoint union)
    repeats: int = 3             # timed runs of each (median)
    which: Literal["best", "periodic"] = "best"   # checkpoint
    per_frame: bool = True       # time the per-frame processor beside it (--no_per_frame: skip)


def _median_time(fn, repeats: int) -> tuple[float, float]:
    """(first call [s] (compilation included), median of ``repeats`` further calls [s])."""
    t0 = time.perf_counter()
    fn()
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return first, statistics.median(times)


def trained_point(workdir: Path, test, *, batch: int, repeats: int, which: str, per_frame: bool = True) -> dict:
    """The trained MGN on the test designs: per-design time (warm), compile time, errors."""
    import dataclasses

    from benchmarks.speed_vs_error import _mesh_build_s, errors
    from pcmgn_jax import metrics
    from pcmgn_jax.eval.baselines import objective_scores
    from pcmgn_jax.scene import Scene
    from pcmgn_jax.surrogates.mgn import MGNSurrogate

    mgn = MGNSurrogate(workdir, test[0], which=which, batch=batch)
    t0 = time.perf_counter()
    pu, pvm = mgn.rollout_trajectories(test)  # a new size bucket: compiled and run once untimed, then timed
    first = time.perf_counter() - t0
    rollout_s = _warm_rollouts(mgn, test, repeats)
    box = "solver" in test[0].meta and mgn.sim.config.data_preset in ("cpu", "paper", "tiny")  # the OCA box
    mesh_s = _design_points_s(test) if box else _mesh_build_s(test[0])
    names = Scene.from_dict(test[0].meta["scene"]).part_names
    obj = {}
    if "OLED" in names:  # a scene without one (a synthetic test scene) has no objective to score
        part = names.index("OLED")
        pred = {"area_mean": np.array([float(metrics.oled_objective_of(t, np.asarray(v), part=part,
                                                                       reading="area_mean"))
                                       for t, v in zip(test, pvm)])}
        obj = objective_scores(test, pred, part=part)
    form = mgn.sim.spec.formulation
    res = dict(mgn_s_per_design=rollout_s / len(test) + mesh_s, mgn_rollout_s_per_design=rollout_s / len(test),
               mesh_build_s=mesh_s, mgn_compile_s=max(first - 2 * rollout_s, 0.0), formulation=dataclasses.asdict(form),
               residual_of=mgn.residual_of,  # a baseline's residual: its prediction is inside the rollout time
               latent=mgn.sim.config.latent_size, message_passing_steps=mgn.sim.config.message_passing_steps,
               objective_error_pct=obj.get("oled_objective_area_rel_error_pct_mean"),
               objective_error_pct_max=obj.get("oled_objective_area_rel_error_pct_max"), **errors(pu, pvm, test))
    if form.processor == "per_design" and per_frame:
        res["mgn_per_frame_s_per_design"] = _per_frame_time(mgn, test, batch=batch, repeats=repeats) + mesh_s
    return res


def _design_points_s(test) -> float:
    """Host time [s] per design to place a new design's nodes: the affine design map of the OCA box
    (:class:`pcmgn_jax.sim.design_map.DesignMap`, built once per scene, as the optimiser and the explorer
    use it; rebuilding the whole mesh per design costs ~0.7 s here and is not needed in this box)."""
    from pcmgn_jax.scene import Scene
    from pcmgn_jax.sim.design_map import DesignMap
    from pcmgn_jax.surrogates.inputs import design_of
    scene = Scene.from_dict(test[0].meta["scene"])
    dmap = DesignMap.build(scene, test[0].meta["solver"]["preset"])
    designs = np.stack([design_of(t) for t in test])
    t0 = time.perf_counter()
    for d in designs:
        dmap.points(d)
    return (time.perf_counter() - t0) / len(designs)


def _warm_rollouts(mgn, test, repeats: int) -> float:
    """Median rollout wall time [s] of ``repeats`` warm calls (host-side batching excluded)."""
    times = []
    for _ in range(repeats):
        mgn.rollout_trajectories(test)
        times.append(mgn.rollout_seconds)
    return statistics.median(times)


def _per_frame_time(mgn, test, *, batch: int, repeats: int) -> float:
    """Rollout seconds per design of the same network run every frame (timing only, see the docstring)."""
    from pcmgn_jax.mgn.rollout import Spec
    s = mgn.sim
    spec = Spec(model=s.spec.model, formulation=s.spec.formulation.replace(processor="per_frame"), dt=s.spec.dt)
    mgn.sim = s._replace(spec=spec)
    try:
        mgn._compiled = set()
        mgn.rollout_trajectories(test)
        per_frame = _warm_rollouts(mgn, test, repeats)
    finally:
        mgn.sim, mgn._compiled = s, set()
    return per_frame / len(test)


def untrained_point(preset: str, n: int, *, repeats: int, per_frame: bool = True) -> dict:
    """The preset's model size, default formulation with the per-design processor, random parameters."""
    import jax

    from benchmarks.rollout_throughput import rollout_setup, union_setup
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.mgn.formulation import FORMULATIONS
    from pcmgn_jax.mgn.rollout import rollout_union

    cfg = TrainConfig.from_preset(preset)
    form = FORMULATIONS["default"].replace(processor="per_design")
    out = {}
    for name, f in (("mgn", form), ("mgn_per_frame", form.replace(processor="per_frame")))[:2 if per_frame else 1]:
        s = rollout_setup(preset, latent=cfg.latent_size, layers=cfg.message_passing_steps, n_designs=n,
                          formulation=f)
        batch, *init = union_setup(s, n)
        fn = lambda: jax.block_until_ready(rollout_union(s["spec"], 100, s["params"], s["stats"], batch, *init))  # noqa
        first, warm = _median_time(fn, repeats)
        out[f"{name}_s_per_design"] = warm / n
        out[f"{name}_compile_s"] = max(first - warm, 0.0)
    out.update(latent=cfg.latent_size, message_passing_steps=cfg.message_passing_steps, n_nodes=s["n_nodes"],
               position_mae_um=None, stress_mae_mpa=None, objective_error_pct=None,
               note="random parameters (no trained run of this preset): timing only")
    return out, s["designs_m"]


def solver_time(preset: str, scenes, n_frames: int, repeats: int) -> dict:
    from benchmarks.speed_vs_error import solver_spec
    from pcmgn_jax.sim import solver
    spec = solver_spec(preset)
    first, warm = _median_time(lambda: solver.simulate(scenes, spec, n_frames=n_frames), max(1, repeats - 2))
    return dict(solver_s_per_design=warm / len(scenes), solver_compile_s=max(first - warm, 0.0))


def main(argv=None) -> dict:
    a = cli.parse(SurrogateSpeedArgs, argv, description=__doc__, prog="python -m benchmarks.surrogate_speed")
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.data.cache import load_split
    from pcmgn_jax.scene import Scene, default_scene

    workdir = Path(a.workdir or f"runs/{a.preset}")
    trained = (workdir / "config.json").exists() and (workdir / "checkpoints").is_dir()
    if trained:
        cfg = TrainConfig.load(workdir / "config.json")
        test = load_split(cfg.resolved_dataset_dir, "test")[:a.n_test or cfg.n_test]
        if not test:
            raise SystemExit(f"{cfg.resolved_dataset_dir}/test holds no trajectories")
        point = trained_point(workdir, test, batch=a.batch, repeats=a.repeats, which=a.which,
                              per_frame=a.per_frame)
        scenes, n_frames = [Scene.from_dict(t.meta["scene"]) for t in test], test[0].n_frames - 1
    else:
        point, designs = untrained_point(a.preset, a.n_test or 8, repeats=a.repeats, per_frame=a.per_frame)
        scenes, n_frames = [default_scene().with_design(*d) for d in designs], 100
    point.update(solver_time(a.preset, scenes, n_frames, a.repeats))
    point["ratio"] = point["solver_s_per_design"] / point["mgn_s_per_design"]
    if "mgn_per_frame_s_per_design" in point:
        point["ratio_per_frame"] = point["solver_s_per_design"] / point["mgn_per_frame_s_per_design"]
    cmd = cli.command_line("benchmarks.surrogate_speed", argv)
    result = dict(preset=a.preset, workdir=str(workdir) if trained else None, trained=trained, n_designs=len(scenes),
                  n_frames=n_frames, batch=a.batch, command=cmd, machine=bench.machine_info(), **point)
    fmt = lambda x, f="{:.3g}": "n/a" if x is None else f.format(x)  # noqa: E731
    rows = [["MGN" + (f" ({workdir})" if trained else " (random parameters)"), fmt(point["mgn_s_per_design"]),
             fmt(point["ratio"]), fmt(point["position_mae_um"]), fmt(point["stress_mae_mpa"]),
             fmt(point["objective_error_pct"])]]
    if "mgn_per_frame_s_per_design" in point:
        rows.append(["same network, processor every frame", fmt(point["mgn_per_frame_s_per_design"]),
                     fmt(point["ratio_per_frame"]), "", "", ""])
    rows.append([f"solver `{a.preset}`", fmt(point["solver_s_per_design"]), "1", "0 (truth)", "0", "0"])
    md = (f"## Surrogate vs solver, preset `{a.preset}` ({len(scenes)} designs, {n_frames} frames)\n\n`{cmd}` — "
          f"{result['machine']['cpu']}, load {result['machine']['load_avg_1min']}\n\n"
          + common.md_table(["predictor", "s / design", "solver / predictor", "position MAE µm",
                             "von Mises MAE MPa", "OLED objective error %"], rows) + "\n")
    jp, mp = common.default_paths(f"surrogate_speed_{a.preset}", a.json, a.md)
    common.write_outputs(result, jp, mp, md)
    return result


if __name__ == "__main__":
    common.run(main)
