"""The MGN family: a trained run's model as a surrogate (``mgn``), and the run's data splits.

    s = fit("mgn", train, workdir="runs/cpu", ref=test[0])   # registry.fit: the run's checkpoint
    us, vms = s.predict_trajectories(test)                   # each from its frame 0, on its own mesh
    u, vm = s.predict(designs_m)                             # designs (B, D) [m], each meshed at the data's preset

The model rolls out from each design's initial state, on that design's mesh (built by
:mod:`pcmgn_jax.sim.mesh` at the training data's preset). A ``residual_of`` run adds its baseline's fields
(fitted by the ``fit_base`` it was given: :func:`registry.fit` passes itself) and the rollout's contact
(:mod:`correction`).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np

from pcmgn_jax.config import TrainConfig
from pcmgn_jax.data.splits import load_splits
from pcmgn_jax.mgn.checkpoint import load
from pcmgn_jax.mgn.inputs import graph_inputs, with_scene
from pcmgn_jax.mgn.rollout import rollout_designs
from pcmgn_jax.scene import Scene
from pcmgn_jax.sim.initial import initial_velocity
from pcmgn_jax.sim.mesh import build_mesh, roi
from pcmgn_jax.surrogates.correction import ball_path, corrected, rigid_contact
from pcmgn_jax.surrogates.kinds import CannotAnswer
from pcmgn_jax.surrogates.objective import FromFields


def run_splits(workdir: str | Path):
    """(cfg, train, val, test) of a training run directory: its ``config.json`` (a
    :class:`~pcmgn_jax.config.TrainConfig`) and :func:`pcmgn_jax.data.splits.load_splits` of its dataset at its
    sizes. ``FileNotFoundError`` when ``workdir`` holds no config.json."""
    run = Path(workdir)
    if not (run / "config.json").exists():
        raise FileNotFoundError(f"{run}/config.json: not a training run directory")
    cfg = TrainConfig.load(run / "config.json")
    return (cfg, *load_splits(cfg.resolved_dataset_dir, n_train=cfg.n_train, n_val=cfg.n_val, n_test=cfg.n_test))


class MGNSurrogate(FromFields):
    """The trained MGN of a run directory as a surrogate (rollout from each design's initial state).

    Many designs roll out ``batch`` at a time as one padded disjoint-union graph
    (:func:`pcmgn_jax.mgn.rollout.rollout_designs`), each on its own mesh: meshes may differ in node
    count and topology. Fields come back stacked, (B, T, N, ...), when every design has the same number
    of nodes, else as lists of per-design arrays (T, N_b, ...).
    """

    name = "mgn"

    def __init__(self, workdir, ref, *, which: str = "best", batch: int = 8, cfg=None, base_trajs=None,
                 fit_base: Callable | None = None):
        """``cfg``: the run's TrainConfig with rollout-only fields changed (e.g. ``contact_projection``);
        None = the run's own config.json. ``base_trajs``: for a ``residual_of`` run, the trajectories its
        baseline is fitted on (None: the run's training split, read when first needed); ``fit_base``:
        (kind, trajs) -> the fitted baseline (:func:`registry.fit`; a residual run needs it)."""
        t0 = time.perf_counter()
        self.workdir = workdir
        self.sim = load(workdir, ref, which=which, cfg=cfg)
        self.fit_seconds, self.warnings = time.perf_counter() - t0, []   # loading the checkpoint
        self.residual_of = self.sim.config.residual_of
        self._base_trajs, self._base, self._fit_base = base_trajs, None, fit_base
        self.base_fit_seconds = 0.0
        self.ref = ref
        self.batch = batch
        self.rollout_seconds = 0.0
        self._compiled: set = set()  # size buckets already compiled (and run once, untimed)

    def _design(self, mesh, u0, v0, vm0, scene: dict | None = None) -> dict:
        """One design for the union rollout: ``mesh`` (points, cells, cell_part, node_type) and its initial
        state; the model's topology and contact buffer when it is the reference mesh, else its own; the
        scene features (if the model has any) of ``scene`` (a scene dict; default the reference's)."""
        s = self.sim
        topology, index = s.topology, s.index
        identity = s.spec.formulation.part_identity
        if not (len(mesh.points) == self.ref.n_nodes and np.array_equal(mesh.cells, self.ref.cells)
                and np.array_equal(mesh.node_type, self.ref.node_type)):
            # role node types: the mesh's own scene names its parts (a stack of another layer count)
            role = identity == "role"
            topology, index, _ = graph_inputs(mesh, (scene if role and scene else self.ref.meta["scene"]),
                                              n_parts=None if role else s.topology.n_node_types - 1,
                                              levels=s.spec.formulation.hierarchy_levels, identity=identity,
                                              radius=s.index.radius, capacity=s.index.capacity)
        topology = with_scene(topology, scene or self.ref.meta["scene"], s.spec.formulation.scene_features)
        return {"topology": topology, "index": index, "points": np.asarray(mesh.points, np.float32),
                "u0": np.asarray(u0, np.float32), "v0": np.asarray(v0, np.float32),
                "vm0": np.asarray(vm0, np.float32)}

    def _rollout(self, designs):
        """Union rollouts of ``designs`` (see :meth:`_design`): (u, vm) stacked or lists (class docstring).
        The first batch of a size bucket compiles (and sizes the contact buffer) outside the timing."""
        s = self.sim
        out = rollout_designs(s.spec, self.ref.n_frames - 1, s.params, s.stats, designs, batch_size=self.batch,
                              compiled=self._compiled, note="the model's rollout")
        self.rollout_seconds = out.seconds
        self.sim = s._replace(index=s.index.replace(capacity=max(s.index.capacity, out.capacity)))
        u = [np.asarray(r.displacement, np.float64) for r in out.rollouts]
        vm = [np.asarray(r.von_mises, np.float64) for r in out.rollouts]
        if len({a.shape for a in u}) == 1:
            return np.stack(u), np.stack(vm)
        return u, vm

    def rollout(self, points, u0, v0, vm0, designs=None):
        """Roll out from initial states (B, N, 2) x3 and (B, N) on the reference mesh's topology:
        (u (B,T,N,2) [m], vm (B,T,N) [Pa]). ``designs`` (B, D) [m]: the designs these meshes are of, for
        the scene features (e.g. ``layer_thickness``); None: the reference's scene."""
        self._whole_fields_only("rollout")
        scenes = [None] * len(points) if designs is None else [self.scene_of(d) for d in designs]
        return self._rollout([dict(self._design(self.ref, u, v, vm, sc), points=np.asarray(p, np.float32))
                              for p, u, v, vm, sc in zip(points, u0, v0, vm0, scenes)])

    def scene_of(self, design) -> dict:
        """The reference scene (a dict) with the design layers' thicknesses ``design`` (D,) [m]."""
        return Scene.from_dict(self.ref.meta["scene"]).with_design(*np.asarray(design, float)).to_dict()

    def rollout_trajectories(self, trajs):
        """Roll out from frame 0 of each trajectory, each on its own mesh (stacked when the node counts
        agree, else lists)."""
        designs = [self._design(t, t.displacement[0], t.velocity[0], t.von_mises[0], t.meta["scene"]) for t in trajs]
        if not self.residual_of:
            return self._rollout(designs)
        t0 = time.perf_counter()
        base = self._baseline_fields(trajs)
        if self.sim.config.residual_ball == "baseline":  # the ball follows the baseline's trajectory
            for d, t, bu in zip(designs, trajs, base[0]):
                d["ball_u"], d["ball_v"] = ball_path(t, bu, self.sim.spec.dt)
        base_s = time.perf_counter() - t0
        u, vm = self._rollout(designs)
        self.rollout_seconds += base_s
        return self._corrected(trajs, u, vm, base)

    def _whole_fields_only(self, what: str):
        if self.residual_of:
            raise CannotAnswer(self.name, f"fields without the queries' scenes (MGNSurrogate.{what})",
                               f"this run predicts the {self.residual_of} baseline's residual (residual_of="
                               f"{self.residual_of!r}), which needs each query's scene parameters: use "
                               "rollout_trajectories with trajectories that carry them")

    def _baseline_fields(self, trajs):
        """A ``residual_of`` run's baseline fields (u list, vm list) on ``trajs``; the baseline is fitted
        once, on the run's training split unless ``base_trajs`` was given (``base_fit_seconds``)."""
        if self._base is None:
            if self._fit_base is None:
                raise ValueError(f"MGNSurrogate: the run {self.workdir} corrects the {self.residual_of} baseline: load "
                                 "it with pcmgn_jax.surrogates.registry.fit('mgn', ...), which fits that baseline")
            t0 = time.perf_counter()
            if self._base_trajs is None:
                self._base_trajs = run_splits(self.workdir)[1]
            self._base = self._fit_base(self.residual_of, self._base_trajs)
            self.base_fit_seconds = time.perf_counter() - t0
        return self._base.predict_trajectories(trajs)

    def _corrected(self, trajs, u, vm, base):
        """A ``residual_of`` run's rollouts (residuals) plus its baseline's fields ``base`` (u, vm lists),
        then the contact projection on the sum when the run's formulation has it
        (:mod:`correction`). The baseline's prediction counts in ``rollout_seconds``."""
        t0 = time.perf_counter()
        u, vm = corrected(trajs, u, vm, *base)
        if self.sim.config.formulation.contact_projection:
            u = [rigid_contact(t, x) for t, x in zip(trajs, u)]
        self.rollout_seconds += time.perf_counter() - t0
        if len({a.shape for a in u}) == 1:
            return np.stack(u), np.stack(vm)
        return u, vm

    def predict(self, designs_m):
        """Designs (B, D) [m] -> fields, each on its own mesh (the training data's scene and preset):
        (u (B,T,N,2), vm (B,T,N)), or lists when the designs' meshes differ in node count."""
        self._whole_fields_only("predict")
        scene = Scene.from_dict(self.ref.meta["scene"])
        preset = self.ref.meta.get("solver", {}).get("preset")
        if preset is None:
            raise ValueError("MGNSurrogate.predict(designs) needs solver-generated training data (meta.solver."
                             "preset); use rollout_trajectories for imported data")
        designs = []
        for d in np.atleast_2d(designs_m):
            one = scene.with_design(*d)
            mesh, _ = roi(build_mesh(one, preset), preset)
            u0, v0, vm0 = self.initial_state(mesh.points[None], node_part=mesh.node_part)
            designs.append(self._design(mesh, u0[0], v0[0], vm0[0], one.to_dict()))
        return self._rollout(designs)

    def initial_state(self, points, node_part=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The solver's initial state on meshes (B, N, 2) [m]: u0 = 0 [m], v0 = the ball's drop velocity on
        ball nodes [m/s], von Mises 0 [Pa]. ``node_part``: the meshes' (N,) parts (default: the reference's)."""
        pts = np.asarray(points, np.float64)
        part = self.ref.node_part if node_part is None else node_part
        v0 = np.broadcast_to(initial_velocity(Scene.from_dict(self.ref.meta["scene"]), part), pts.shape).copy()
        return np.zeros_like(pts), v0, np.zeros(pts.shape[:2])

    def predict_trajectories(self, trajs):
        """The surrogate interface's name of :meth:`rollout_trajectories`."""
        return self.rollout_trajectories(trajs)


def fit(kind: str, train_trajs=(), *, workdir, ref=None, which: str = "best", batch: int = 8, cfg=None,
        fit_base: Callable | None = None) -> MGNSurrogate:
    """The run in ``workdir`` as the ``mgn`` kind: ``ref`` the reference trajectory (default the first of
    ``train_trajs``), ``train_trajs`` what a residual run's baseline is fitted on (empty: the run's training
    split, read when first needed)."""
    train = list(train_trajs)
    if ref is None:
        if not train:
            raise ValueError("mgn: needs a reference trajectory (ref) or training trajectories")
        ref = train[0]
    return MGNSurrogate(workdir, ref, which=which, batch=batch, cfg=cfg, base_trajs=train or None, fit_base=fit_base)

