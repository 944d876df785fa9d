"""Surrogates behind one small interface: designs in, fields out.

    s = fit_baseline("rbf", train_trajs)              # or "none", "nearest", "poly2"; or MGNSurrogate(...)
    u, vm = s.predict(designs_m)                      # (B, T, N, 2) [m], (B, T, N) [Pa]

``designs_m`` is (B, D) [m], the thicknesses of the scene's ``design_layers`` (in the trajectories'
``meta['design']`` order). The baselines are fitted on the training split only and need a shared
topology (every training and predicted design has the same node numbering: true for the built-in
solver's meshes at a fixed preset, where a design moves nodes but never renumbers them):

- ``none``     nothing moves, zero stress (u = u_0 of the first training trajectory, i.e. 0)
- ``nearest``  the training trajectory whose design is nearest (Euclidean, in µm)
- ``poly2``    per node, frame and channel, a least-squares quadratic in the design variables
               (coordinates scaled to [-1, 1] over the training box)
- ``rbf``      per node, frame and channel, ``scipy.interpolate.RBFInterpolator`` (thin-plate spline
               with a linear tail) over the scaled design variables

When the meshes differ (a scene family: ball radius, drop speed and layer thicknesses vary, and with
them the node count), :class:`NearestScene` gives the two baselines that need no shared node numbering:
``none`` and ``nearest`` (the nearest training scene in normalised scene-parameter space, its fields
carried over to the test mesh); ``poly2`` and ``rbf`` do not apply there.

The MGN surrogate rolls the trained model out from each design's initial state, on that design's mesh
(built by :mod:`pcmgn_jax.sim.mesh` at the training data's preset).
"""
from __future__ import annotations

import time
from itertools import combinations_with_replacement
from typing import Sequence

import numpy as np

BASELINES = ("none", "nearest", "poly2", "rbf")


def design_of(traj) -> np.ndarray:
    """(D,) design [m] of a trajectory, in its scene's ``design_layers`` order."""
    d = traj.meta.get("design")
    layers = traj.meta.get("scene", {}).get("design_layers")
    if isinstance(d, dict):
        return np.array([float(d[k]) for k in (layers or d)])
    if d is None:
        raise ValueError(f"trajectory {traj.meta.get('name', '?')}: meta has no 'design'")
    return np.asarray(d, np.float64)


def scene_vector(traj) -> tuple[tuple[str, ...], np.ndarray]:
    """(names, values [SI]) of what distinguishes a trajectory's scene: meta['scene_params'] of a scene
    family (ball radius [m], drop speed [m/s], layer thicknesses [m]), else its design (:func:`design_of`)."""
    params = traj.meta.get("scene_params")
    if params:
        names = tuple(sorted(params))
        return names, np.array([float(params[k]) for k in names])
    layers = tuple(traj.meta.get("scene", {}).get("design_layers") or ())
    return layers, design_of(traj)


def _layer_bounds(scene: dict) -> tuple[np.ndarray, np.ndarray]:
    """(bottom, top) heights [m] of the part ids 1.. (layers from the top), plate bottom at y = 0."""
    t = np.array([layer["thickness"] for layer in scene["layers"]], np.float64)
    tops = t[::-1].cumsum()[::-1]
    return tops - t, tops


def part_coordinates(points, node_part, scene: dict) -> np.ndarray:
    """(N, 2) part-relative coordinates of reference ``points`` [m]: a layer node keeps x and gets its
    height's fraction through its layer's thickness (+ the part id, so layers never mix); a ball node
    gets its offset from the ball's lowest point divided by the radius. Two scenes' nodes with equal
    coordinates sit at the same place relative to their parts (the carry-over rule of :class:`NearestScene`)."""
    pts = np.asarray(points, np.float64)
    part = np.asarray(node_part)
    lo, hi = _layer_bounds(scene)
    out = np.empty_like(pts)
    ball = part == 0
    R = float(scene["ball"]["radius"])
    bottom = hi[0] + float(scene["ball"]["gap"])
    out[ball] = np.stack([pts[ball, 0] / R, (pts[ball, 1] - bottom) / R], axis=1)
    k = part[~ball] - 1
    out[~ball] = np.stack([pts[~ball, 0], part[~ball] + (pts[~ball, 1] - lo[k]) / (hi[k] - lo[k])], axis=1)
    return out


def transfer_fields(src, dst_points, dst_node_part, dst_scene: dict) -> tuple[np.ndarray, np.ndarray]:
    """Trajectory ``src``'s displacement (T, N, 2) [m] and von Mises (T, N) [Pa] carried over to another
    mesh of another scene: per part, linear interpolation over ``src``'s nodes in part-relative coordinates
    (:func:`part_coordinates`, scaled to the part's extent), nearest node outside their hull."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator, interp1d
    from scipy.spatial import QhullError

    a = part_coordinates(src.points, src.node_part, src.meta["scene"])
    b = part_coordinates(dst_points, dst_node_part, dst_scene)
    values = np.concatenate([np.asarray(src.displacement, np.float64),
                             np.asarray(src.von_mises, np.float64)[..., None]], axis=-1)  # (T, N, 3)
    T = values.shape[0]
    out = np.zeros((T, len(b), 3))
    src_part, dst_part = np.asarray(src.node_part), np.asarray(dst_node_part)
    for k in np.unique(dst_part):
        s_sel, d_sel = src_part == k, dst_part == k
        if not s_sel.any():
            raise ValueError(f"field transfer: part {k} has no nodes in {src.meta.get('name', 'the source')}")
        lo, span = a[s_sel].min(0), np.maximum(np.ptp(a[s_sel], axis=0), 1e-30)
        xa, xb = (a[s_sel] - lo) / span, (b[d_sel] - lo) / span
        vals = values[:, s_sel].transpose(1, 0, 2).reshape(s_sel.sum(), -1)
        try:
            got = LinearNDInterpolator(xa, vals)(xb)
        except QhullError:  # the part's nodes lie on one line (e.g. one row): interpolate along it
            axis = int(np.argmax(np.ptp(xa, axis=0)))
            order = np.argsort(xa[:, axis], kind="stable")
            got = interp1d(xa[order, axis], vals[order], axis=0, bounds_error=False,
                           fill_value=np.nan, assume_sorted=True)(xb[:, axis]) if len(order) > 1 else \
                np.full((d_sel.sum(), vals.shape[1]), np.nan)
        miss = np.isnan(got).any(axis=1)
        if miss.any():
            got[miss] = NearestNDInterpolator(xa, vals)(xb[miss])
        out[:, d_sel] = got.reshape(d_sel.sum(), T, 3).transpose(1, 0, 2)
    return out[..., :2], out[..., 2]


def part_names_of(traj) -> tuple[str, ...]:
    """A trajectory's part names (0 the ball, then its layers from the top): meta['part_names'], else its scene's."""
    names = traj.meta.get("part_names")
    if names is None:
        names = ["ball"] + [layer["name"] for layer in (traj.meta.get("scene") or {}).get("layers", ())]
    return tuple(names)


class NearestScene:
    """Baselines across meshes: the nearest training scene (scene parameters scaled to [-1, 1] over the
    training box, Euclidean) among those with the query's layers (:func:`part_names_of`; fields map part by
    part, so a stack of other layers has none: ValueError naming it), its fields carried over to each test
    mesh (:func:`transfer_fields`), or with ``zero`` nothing moves (zero fields on each test mesh)."""

    def __init__(self, train_trajs: Sequence, *, zero: bool = False):
        if not train_trajs:
            raise ValueError("a baseline needs at least one training trajectory")
        t0 = time.perf_counter()
        self.trajs, self.zero = list(train_trajs), zero
        names = {scene_vector(t)[0] for t in self.trajs}
        if len(names) != 1:
            raise ValueError(f"nearest scene: the training trajectories describe their scenes differently: {names}")
        self.names = names.pop()
        self.x = np.stack([scene_vector(t)[1] for t in self.trajs])
        self.lo, self.hi = self.x.min(0), self.x.max(0)
        self.fit_seconds = time.perf_counter() - t0

    def _scale(self, d):
        return 2 * (np.asarray(d, np.float64) - self.lo) / np.where(self.hi > self.lo, self.hi - self.lo, 1.0) - 1

    def nearest(self, traj) -> int:
        names, v = scene_vector(traj)
        if names != self.names:
            raise ValueError(f"nearest scene: {traj.meta.get('name', '?')} has scene parameters {names}, the "
                             f"training scenes {self.names}")
        parts = part_names_of(traj)
        same = np.array([part_names_of(t) == parts for t in self.trajs])
        if not same.any():
            raise ValueError(f"nearest scene: no training scene has the parts {list(parts)} of "
                             f"{traj.meta.get('name', '?')}: a field does not map onto a stack of other layers")
        d = ((self._scale(v)[None] - self._scale(self.x)) ** 2).sum(-1)
        return int(np.argmin(np.where(same, d, np.inf)))

    def predict_trajectories(self, trajs) -> tuple[list, list]:
        """Per test trajectory (on its own mesh): displacement (T, N, 2) [m] and von Mises (T, N) [Pa]."""
        us, vms = [], []
        for t in trajs:
            if self.zero:
                us.append(np.zeros(np.shape(t.displacement)))
                vms.append(np.zeros(np.shape(t.von_mises)))
                continue
            u, vm = transfer_fields(self.trajs[self.nearest(t)], t.points, t.node_part, t.meta["scene"])
            us.append(u)
            vms.append(vm)
        return us, vms


def _fields(trajs) -> np.ndarray:
    """(B, T*N*3) float64: displacement x, y and von Mises of every frame and node."""
    return np.stack([np.concatenate([np.asarray(t.displacement, np.float64),
                                     np.asarray(t.von_mises, np.float64)[..., None]], axis=-1).reshape(-1)
                     for t in trajs])


class FieldRegression:
    """A baseline fitted on training trajectories of one topology (see the module docstring)."""

    def __init__(self, kind: str, train_trajs: Sequence):
        if kind not in BASELINES:
            raise ValueError(f"baseline must be one of {BASELINES}, got {kind!r}")
        if not train_trajs:
            raise ValueError("a baseline needs at least one training trajectory")
        ref = train_trajs[0]
        for t in train_trajs:
            if t.displacement.shape != ref.displacement.shape or not np.array_equal(t.cells, ref.cells):
                raise ValueError(f"baseline {kind!r}: per-node regression needs one shared topology; "
                                 f"{t.meta.get('name', '?')} differs from {ref.meta.get('name', '?')}")
        self.name = kind
        self.shape = ref.displacement.shape  # (T, N, 2)
        self.x = np.stack([design_of(t) for t in train_trajs])
        self.lo, self.hi = self.x.min(0), self.x.max(0)
        t0 = time.perf_counter()
        if kind == "poly2":
            self.y = _fields(train_trajs)
            A = self._poly(self._scale(self.x))
            if A.shape[0] < A.shape[1]:
                raise ValueError(f"poly2 needs >= {A.shape[1]} training designs, got {A.shape[0]}")
            self.coef = np.linalg.lstsq(A, self.y, rcond=None)[0]
        elif kind == "rbf":
            from scipy.interpolate import RBFInterpolator
            self.rbf = RBFInterpolator(self._scale(self.x), _fields(train_trajs), kernel="thin_plate_spline",
                                       degree=1)
        elif kind == "nearest":
            self.y = _fields(train_trajs)
        self.fit_seconds = time.perf_counter() - t0

    def _scale(self, d):
        return 2 * (np.asarray(d, np.float64) - self.lo) / np.where(self.hi > self.lo, self.hi - self.lo, 1.0) - 1

    @staticmethod
    def _poly(z) -> np.ndarray:
        cols = [np.ones(len(z))] + [z[:, i] for i in range(z.shape[1])]
        cols += [z[:, i] * z[:, j] for i, j in combinations_with_replacement(range(z.shape[1]), 2)]
        return np.stack(cols, axis=1)

    def predict(self, designs_m) -> tuple[np.ndarray, np.ndarray]:
        d = np.atleast_2d(np.asarray(designs_m, np.float64))
        B = len(d)
        if self.name == "none":
            flat = np.zeros((B, int(np.prod(self.shape[:2])) * 3))
        elif self.name == "nearest":
            k = np.argmin(((d[:, None] - self.x[None]) ** 2).sum(-1), axis=1)
            flat = self.y[k]
        elif self.name == "poly2":
            flat = self._poly(self._scale(d)) @ self.coef
        else:
            flat = self.rbf(self._scale(d))
        f = flat.reshape((B,) + self.shape[:2] + (3,))
        return f[..., :2], f[..., 2]


class MGNSurrogate:
    """The trained MGN of a run directory as a surrogate (rollout from each design's initial state).

    Many designs roll out ``batch`` at a time as one padded disjoint-union graph
    (:func:`pcmgn_jax.mgn.rollout.rollout_designs`), each on its own mesh: meshes may differ in node
    count and topology. Fields come back stacked, (B, T, N, ...), when every design has the same number
    of nodes, else as lists of per-design arrays (T, N_b, ...).
    """

    name = "mgn"

    def __init__(self, workdir, ref, *, which: str = "best", batch: int = 8, cfg=None, base_trajs=None):
        """``cfg``: the run's TrainConfig with rollout-only fields changed (e.g. ``contact_projection``);
        None = the run's own config.json. ``base_trajs``: for a ``residual_of`` run, the trajectories its
        baseline is fitted on (None: the run's training split, read when first needed)."""
        from pcmgn_jax.mgn.checkpoint import load
        self.workdir = workdir
        self.sim = load(workdir, ref, which=which, cfg=cfg)
        self.residual_of = self.sim.config.residual_of
        self._base_trajs, self._base = base_trajs, None
        self.base_fit_seconds = 0.0
        self.ref = ref
        self.batch = batch
        self.rollout_seconds = 0.0
        self._compiled: set = set()  # size buckets already compiled (and run once, untimed)

    def _design(self, mesh, u0, v0, vm0, scene: dict | None = None) -> dict:
        """One design for the union rollout: ``mesh`` (points, cells, cell_part, node_type) and its initial
        state; the model's topology and contact buffer when it is the reference mesh, else its own; the
        scene features (if the model has any) of ``scene`` (a scene dict; default the reference's)."""
        from pcmgn_jax.mgn.inputs import graph_inputs, with_scene
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
        from pcmgn_jax.mgn.rollout import rollout_designs
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
        from pcmgn_jax.scene import Scene
        return Scene.from_dict(self.ref.meta["scene"]).with_design(*np.asarray(design, float)).to_dict()

    def rollout_trajectories(self, trajs):
        """Roll out from frame 0 of each trajectory, each on its own mesh (stacked when the node counts
        agree, else lists)."""
        designs = [self._design(t, t.displacement[0], t.velocity[0], t.von_mises[0], t.meta["scene"]) for t in trajs]
        if not self.residual_of:
            return self._rollout(designs)
        from pcmgn_jax.eval.residual import ball_path
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
            raise ValueError(f"MGNSurrogate.{what}: this run predicts the {self.residual_of} baseline's residual "
                             f"(residual_of={self.residual_of!r}), which needs each query's scene parameters: "
                             "use rollout_trajectories with trajectories that carry them")

    def _baseline_fields(self, trajs):
        """A ``residual_of`` run's baseline fields (u list, vm list) on ``trajs``; the baseline is fitted
        once, on the run's training split unless ``base_trajs`` was given (``base_fit_seconds``)."""
        from pcmgn_jax.eval.residual import fit_baseline
        if self._base is None:
            t0 = time.perf_counter()
            if self._base_trajs is None:
                from pcmgn_jax.eval.pipeline import run_splits
                self._base_trajs = run_splits(self.workdir)[1]
            self._base = fit_baseline(self.residual_of, self._base_trajs)
            self.base_fit_seconds = time.perf_counter() - t0
        return self._base.predict_trajectories(trajs)

    def _corrected(self, trajs, u, vm, base):
        """A ``residual_of`` run's rollouts (residuals) plus its baseline's fields ``base`` (u, vm lists),
        then the contact projection on the sum when the run's formulation has it
        (:mod:`pcmgn_jax.eval.residual`). The baseline's prediction counts in ``rollout_seconds``."""
        from pcmgn_jax.eval.residual import corrected, rigid_contact
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
        from pcmgn_jax.scene import Scene
        from pcmgn_jax.sim.mesh import build_mesh, roi
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
        from pcmgn_jax.scene import Scene
        from pcmgn_jax.sim.initial import initial_velocity
        pts = np.asarray(points, np.float64)
        part = self.ref.node_part if node_part is None else node_part
        v0 = np.broadcast_to(initial_velocity(Scene.from_dict(self.ref.meta["scene"]), part), pts.shape).copy()
        return np.zeros_like(pts), v0, np.zeros(pts.shape[:2])


def poly2_features(z) -> np.ndarray:
    """(B, (D + 1)(D + 2) / 2) the poly2 baseline's features of scaled inputs z (B, D): 1, z_i, z_i z_j (i <= j)."""
    return FieldRegression._poly(np.atleast_2d(np.asarray(z, np.float64)))
