"""Everything derived once from the training split (host side): per-trajectory graphs (topology, contact
candidates, noise levels, loss weights, penetration boundary), the union size bucket, the statistics.

    setup = prepare(cfg, train_trajs)        # Setup(spec, graphs, sizes, stats, ...)

Trajectories may have different meshes (a scene family, imported data): every quantity that belongs to
a graph is kept per trajectory (:class:`GraphParts`), and a training step sees a padded disjoint union
of ``batch_graphs`` of them (:func:`pcmgn_jax.train.sampling.gather_unions`) padded to one static size
for the whole dataset (:class:`UnionSizes`: the largest graphs of the split, bucketed), so the jitted
step compiles once. Trajectories with the same mesh (cells and node types) share one topology, contact
candidate set, penetration boundary and loss weights, taken from the first of them (a single-topology
dataset: exactly one, as before).

The statistics are computed on exactly what the loss sees: the same :func:`pcmgn_jax.train.noise`
draws and target corrections as the training step (the paper's target correction −n/Δt is 7× the
clean x-velocity spread at 0.3 µm noise, so statistics of the clean targets would mis-scale the loss),
over the real nodes of every training trajectory (never padding).
"""
from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import jax
import numpy as np

from pcmgn_jax.config import TrainConfig
from pcmgn_jax.geometry import roi_boundary_nodes
from pcmgn_jax.metrics import objective_weights
from pcmgn_jax.mgn import contact as contact_lib
from pcmgn_jax.mgn.batching import bucket_size
from pcmgn_jax.mgn.checkpoint import make_spec
from pcmgn_jax.mgn.formulation import BALL_PART, Formulation, is_ball, model_inputs
from pcmgn_jax.mgn.graphs import Topology
from pcmgn_jax.mgn.hierarchy import level_sizes
from pcmgn_jax.mgn.inputs import contact_radius, graph_inputs, topology_from_trajectory, with_scene
from pcmgn_jax.mgn.normalization import Accumulator, Stats, TypedAccumulator, make_stats
from pcmgn_jax.mgn.rollout import Spec, input_graph
from pcmgn_jax.mgn.scene_features import across_part_channels
from pcmgn_jax.scene import Scene
from pcmgn_jax.train import startup_cache
from pcmgn_jax.train.noise import motion_rms, noise_parts_mask, noise_sigma, perturb
from pcmgn_jax.train.sampling import pair_table, sample


@dataclass(frozen=True)
class TrainSpec:
    """Static (hashable) training settings: the jit cache key of ``train_chunk``."""

    sim: Spec
    cfg: TrainConfig             # learning rate, lambda_pen, polynomial degrees, ... (one copy)
    decay_steps: int             # resolved lr_decay_steps (0 in the config -> total steps)
    pen_interval: tuple = (0.0, 1.0)  # [m] fixed fit interval of the penetration term


class GraphParts(NamedTuple):
    """One training trajectory's graph quantities (host, NumPy; node arrays over its own N nodes)."""

    topology: Topology
    index: contact_lib.ContactIndex
    sigma: np.ndarray        # [N] float32 noise std per node [m] (0: not noised)
    motion: np.ndarray       # [N] float32 loss weights of the motion channels (sum 1 over the graph)
    stress: np.ndarray       # [N] float32 loss weights of the stress channel
    ball: float              # weight of the rigid ball's motion term
    perturbed: np.ndarray    # [N] float32 1 on the noised parts' free nodes
    pen_ball: np.ndarray     # [Mb] int32 ball-bottom nodes of the penetration fits
    pen_panel: np.ndarray    # [Mp] int32 CG-top nodes
    objective: np.ndarray | None = None  # [N] float32 the objective's section weights (sum 1, OLED) when lambda_obj > 0


class UnionSizes(NamedTuple):
    """The static size of every training union (one bucket per dataset: one compilation)."""

    nodes: int
    edges: int
    slots: int               # real graph slots (graphs per union); +1 padding graph
    ball: int                # contact candidates per graph
    panel: int
    capacity: int            # contact edges per graph
    pen_ball: int            # penetration boundary nodes per graph
    pen_panel: int
    levels: tuple = ()       # (nodes, edges) of every coarse level (reach='multiscale'), padding included


class Setup(NamedTuple):
    spec: TrainSpec
    graphs: list             # [GraphParts] one per training trajectory (shared objects for one mesh)
    sizes: UnionSizes
    stats: Stats
    scene: Scene
    n_pairs: int             # (trajectory, frame) training pairs
    total_steps: int

    @property
    def radius(self) -> float:
        """Contact radius r_w [m] (one for the dataset)."""
        return self.graphs[0].index.radius


def output_dt(traj) -> float:
    return float(traj.meta.get("output_dt") or (traj.times[1] - traj.times[0]))


def scene_of(traj) -> Scene:
    return Scene.from_dict(traj.meta["scene"])


def total_steps(cfg: TrainConfig, n_pairs: int) -> int:
    steps = cfg.num_steps or math.ceil(cfg.epochs * n_pairs / cfg.batch_graphs)
    k = cfg.steps_per_dispatch
    return int(k * math.ceil(steps / k))


def penetration_nodes(cfg: TrainConfig, ref, panel_part: int):
    """Ball-bottom / CG-top node sets and fit interval (:func:`pcmgn_jax.geometry.roi_boundary_nodes`)."""
    return roi_boundary_nodes(ref, panel_part, x_max=cfg.pen_x_max)


def loss_weights(form: Formulation, topology: Topology) -> dict:
    """Per-node loss weights of one graph (each channel's weights sum to 1).

    'nodes': the mean over the free nodes (motion) and all nodes (stress), the paper's MSE.
    'parts': the mean over node types of each type's node mean, so every part counts alike.
    A rigid ball's motion is one term (weight = its nodes' share) instead of one per node.
    """
    node_type = np.asarray(topology.node_type)
    free = ~np.asarray(topology.fixed)
    ball = node_type == BALL_PART

    def spread(sel):
        w = np.zeros(node_type.shape)
        if form.loss_weighting == "nodes":
            w[sel] = 1.0 / max(sel.sum(), 1)
        else:
            types = np.unique(node_type[sel])
            for k in types:
                m = sel & (node_type == k)
                w[m] = 1.0 / (len(types) * m.sum())
        return w

    motion = spread(free)
    w_ball = 0.0
    if form.rigid_ball:
        w_ball = float(motion[ball].sum())
        motion[ball] = 0.0
    return {"motion": motion.astype(np.float32), "ball": np.float32(w_ball),
            "stress": spread(np.ones(node_type.shape, bool)).astype(np.float32)}


def emphasise_part(w: np.ndarray, node_part, part: int, factor: float) -> np.ndarray:
    """(N,) float32: the loss weights ``w`` (sum 1 over the graph) with the nodes of ``part`` (``node_part``
    (N,), the trajectory's part id per node) multiplied by ``factor`` and the whole rescaled to sum 1 again
    (the ``oled_stress_weight`` option: the OLED's share of the stress term). ``factor`` = 1 returns ``w``."""
    if factor == 1.0:
        return w
    out = np.where(np.asarray(node_part) == part, factor, 1.0) * np.asarray(w, np.float64)
    return (out / max(out.sum(), np.finfo(np.float64).tiny)).astype(np.float32)


def oled_part(scene: Scene, option: str) -> int:
    """The part id of the scene's 'OLED' (the objective's layer); ValueError naming ``option`` when it has none."""
    if "OLED" not in scene.part_names:
        raise ValueError(f"{option} needs a part named 'OLED' (the objective's layer); "
                         f"the scene has {list(scene.part_names)}")
    return scene.part_names.index("OLED")


def objective_loss_weights(traj, scene: Scene) -> np.ndarray:
    """(N,) float32 nodal weights (sum 1) of the design objective's reading (the default, area mean over
    the OLED's section under the ball: :func:`pcmgn_jax.metrics.objective_weights`, the same rule
    the evaluation scores) on one trajectory's mesh, for the ``lambda_obj`` term. ValueError when the
    scene has no part named 'OLED'."""
    w = objective_weights(traj.points, traj.cells, traj.cell_part, traj.node_part,
                          part=oled_part(scene, "lambda_obj > 0"))
    return np.asarray(w, np.float32)


@functools.partial(jax.jit, static_argnames=("spec",))
def _noisy_features(spec: Spec, topology, index, sigma, smp, key, n):
    form = spec.formulation
    smp = perturb(spec, topology, smp, sigma, jax.random.fold_in(key, n))  # pair n's draw, inside the one call
    g, edges = input_graph(form, topology, index, smp["points"], smp["u"], smp["v"])
    return (g.nodes[:, topology.n_node_types:], g.edges["mesh"].features, g.edges["contact"].features,
            edges.mask, smp["target"], smp["ball"])


def _per_trajectory(x, n: int, name: str) -> list:
    """``x`` for each of n trajectories: a list of n, or one object shared by all."""
    if isinstance(x, (list, tuple)):
        if len(x) != n:
            raise ValueError(f"compute_stats: {len(x)} {name} for {n} trajectories")
        return list(x)
    return [x] * n


def compute_stats(spec: Spec, trajs, topology, index, sigma, *, max_frames: int = 2000,
                  seed: int = 0) -> Stats:
    """Statistics of the inputs and targets the loss sees (noise and correction included), per node
    type (``per_part``) or over all nodes (``global``); every pair when <= max_frames exist.

    ``topology``, ``index``, ``sigma``: one per trajectory (lists; each trajectory on its own mesh, so no
    padding enters the sums), or one shared by all (a single-topology dataset)."""
    form = spec.formulation
    topos = _per_trajectory(topology, len(trajs), "topologies")
    indices = _per_trajectory(index, len(trajs), "contact indices")
    sigmas = _per_trajectory(sigma, len(trajs), "sigma arrays")
    pairs = pair_table(trajs)
    if len(pairs) > max_frames:
        pairs = pairs[np.linspace(0, len(pairs) - 1, max_frames).round().astype(int)]
    T = topos[0].n_node_types
    n_scene = 0 if topos[0].scene_features is None else int(np.shape(topos[0].scene_features)[1])
    n_phys = 6 if form.features == "strain" else 4
    n_node = n_phys + n_scene + form.node_extra
    acc = {"node": TypedAccumulator(T, n_node), "mesh": TypedAccumulator(T, 6), "contact": Accumulator(3),
           "motion": TypedAccumulator(T, 2), "stress": TypedAccumulator(T, 1), "ball": Accumulator(2)}
    key = jax.random.PRNGKey(seed)
    def f32(d):
        return {k: np.asarray(v, np.float32) for k, v in d.items()}
    for n, (i, t) in enumerate(pairs):
        topo = topos[i]
        node_type = np.asarray(topo.node_type)
        # motion targets of the free nodes that move on their own (not a rigid ball's), stress of all nodes
        moving = ~np.asarray(topo.fixed) & ~((node_type == BALL_PART) & form.rigid_ball)
        smp = f32(sample(form, trajs[i], int(t), spec.dt))
        node, mesh, cont, mask, target, ball = _noisy_features(spec, topo, indices[i], sigmas[i], smp, key, n)
        acc["node"].add(node, node_type)
        acc["mesh"].add(mesh, node_type[np.asarray(topo.mesh_receivers)])
        acc["contact"].add(cont, np.asarray(mask))
        target = np.asarray(target)
        acc["motion"].add(target[:, :2], node_type, moving)
        acc["stress"].add(target[:, 2:], node_type)
        if form.rigid_ball:
            acc["ball"].add(np.asarray(ball)[None])
    across = [n_phys + i for i in across_part_channels(trajs[0].meta.get("scene") or {}, form.scene_features)]
    return make_stats(**acc, per_part=form.normalization == "per_part",
                      contact_default_std=indices[0].radius, node_across=across)


def contact_positions(form: Formulation, traj) -> np.ndarray:
    """(T, N, 2) [m] the positions the contact search sees in the model's inputs of every frame of
    ``traj`` (:func:`pcmgn_jax.mgn.formulation.model_inputs`: a quasi-static panel at its reference)."""
    ball, points = is_ball(traj.node_type), np.asarray(traj.points, np.float64)
    return np.stack([points + model_inputs(form, ball, u, u)[0] for u in np.asarray(traj.displacement, np.float64)])


def mesh_key(traj) -> tuple:
    """Trajectories with equal keys share one mesh topology (cells and node types)."""
    return (traj.n_nodes, np.asarray(traj.cells).tobytes(), np.asarray(traj.node_type).tobytes())


def graph_for(setup: Setup, traj) -> dict:
    """A trajectory outside the training split as a design for :func:`pcmgn_jax.mgn.rollout.rollout_designs`
    (its topology with its scene features, a contact index of the training radius and buffer size)."""
    form = setup.spec.sim.formulation
    inp = graph_inputs(traj, traj.meta["scene"], scene_features=form.scene_features, levels=form.hierarchy_levels,
                       radius=setup.radius, capacity=setup.sizes.capacity, identity=form.part_identity)
    return inp._asdict()


def prepare(cfg: TrainConfig, train_trajs: Sequence, *, stats_max_frames: int = 2000,
            capacity: int | None = None, radius: float | None = None, stats: Stats | None = None) -> Setup:
    """Per-trajectory graphs (topology, contact buffer sized on the training frames, noise levels, loss
    weights, penetration boundary), the union size bucket, and the normalisation statistics (computed
    unless ``stats`` is given, e.g. from a checkpoint on resume). Trajectories may have different meshes;
    they must share the scene's parts (node types; with ``part_identity='role'`` only the roles, so stacks of
    different layer counts train together), the frame interval and the contact pair."""
    if not train_trajs:
        raise ValueError("no training trajectories")
    ref = train_trajs[0]
    scene = scene_of(ref)
    dt = output_dt(ref)
    for i, t in enumerate(train_trajs):
        name = t.meta.get("name", "?")
        if not math.isclose(output_dt(t), dt, rel_tol=1e-9):
            raise ValueError(f"training trajectory {i} ({name}): output_dt {output_dt(t)} s differs from "
                             f"trajectory 0's {dt} s; one frame interval per dataset")
        if scene_of(t).part_names != scene.part_names and cfg.formulation.part_identity != "role":
            raise ValueError(f"training trajectory {i} ({name}): parts {scene_of(t).part_names} differ from "
                             f"trajectory 0's {scene.part_names}; one set of node types per dataset")
    form = cfg.formulation
    panel_part = contact_lib.contact_parts(scene)[1]
    r_w = radius or cfg.contact_radius or contact_radius(ref, scene)
    groups: dict[tuple, list[int]] = {}
    for i, t in enumerate(train_trajs):
        groups.setdefault(mesh_key(t), []).append(i)
    n_types = topology_from_trajectory(ref, identity=form.part_identity).n_node_types
    rms = None
    if cfg.noise_rel > 0:
        types = [topology_from_trajectory(t, identity=form.part_identity).node_type for t in train_trajs]
        rms = motion_rms(train_trajs, n_types, types)
    shared, intervals = {}, []
    for key, members in groups.items():
        g_ref = train_trajs[members[0]]
        topo, index, _ = graph_inputs(g_ref, scene_of(g_ref), radius=r_w, levels=form.hierarchy_levels,
                                      identity=form.part_identity,
                                      positions=[contact_positions(form, train_trajs[i]) for i in members],
                                      capacity_factor=cfg.contact_capacity_factor, capacity=capacity)
        pen_ball, pen_panel = np.zeros(0, np.int32), np.zeros(0, np.int32)
        if cfg.lambda_pen > 0:
            bn = penetration_nodes(cfg, g_ref, panel_part)
            intervals.append(bn.interval)
            pen_ball, pen_panel = np.asarray(bn.ball, np.int32), np.asarray(bn.panel, np.int32)
        w = loss_weights(form, topo)
        if cfg.oled_stress_weight != 1.0:
            oled = oled_part(scene_of(g_ref), "oled_stress_weight != 1")
            w["stress"] = emphasise_part(w["stress"], g_ref.node_part, oled, cfg.oled_stress_weight)
        w_obj = objective_loss_weights(g_ref, scene_of(g_ref)) if cfg.lambda_obj > 0 else None
        sigma = noise_sigma(topo.node_type, g_ref.node_part, topo.fixed, parts=cfg.noise_parts,
                            noise_std=cfg.noise_std, noise_rel=cfg.noise_rel, rms=rms)
        shared[key] = GraphParts(topo, index, sigma, w["motion"], w["stress"], float(w["ball"]),
                                 noise_parts_mask(g_ref.node_part, cfg.noise_parts,
                                                  fixed=topo.fixed).astype(np.float32),
                                 pen_ball, pen_panel, w_obj)
    # one buffer size per dataset: the largest any mesh needs
    cap = max(p.index.capacity for p in shared.values())
    graphs = []
    for t in train_trajs:
        p = shared[mesh_key(t)]
        topo = with_scene(p.topology, t.meta["scene"], form.scene_features)
        graphs.append(p._replace(topology=topo, index=p.index.replace(capacity=cap)))
    interval = (0.0, 1.0)
    if intervals:  # one fixed fit interval covering every mesh's boundary (one mesh: its own)
        interval = (float(min(iv[0] for iv in intervals)), float(max(iv[1] for iv in intervals)))
    sim = make_spec(cfg, dt)
    n_pairs = sum(t.n_frames - 1 for t in train_trajs)
    steps = total_steps(cfg, n_pairs)
    spec = TrainSpec(sim=sim, cfg=cfg, decay_steps=cfg.lr_decay_steps or steps, pen_interval=interval)
    from pcmgn_jax.train.sharding import resolve_devices
    sizes = union_sizes(graphs, per_union=max(1, cfg.batch_graphs // resolve_devices(cfg.devices)), capacity=cap)
    if stats is None:  # kept beside the compiled programs: a warm start reads them (train/startup_cache.py)
        stats = startup_cache.stats(cfg, train_trajs, dict(max_frames=stats_max_frames, radius=r_w, capacity=cap),
                                   lambda: compute_stats(sim, train_trajs, [g.topology for g in graphs],
                                                         [g.index for g in graphs], [g.sigma for g in graphs],
                                                         max_frames=stats_max_frames, seed=cfg.seed))
    return Setup(spec, graphs, sizes, stats, scene, n_pairs, steps)


def union_sizes(graphs: Sequence[GraphParts], *, per_union: int, capacity: int) -> UnionSizes:
    """The one static size of a training union of ``per_union`` graphs: room for ``per_union`` copies of
    the dataset's largest graph (a step may draw it that often), bucketed
    (:func:`pcmgn_jax.mgn.batching.bucket_size`)."""
    def top(vals):
        return per_union * max(vals)
    return UnionSizes(nodes=bucket_size(top([g.topology.n_node for g in graphs]) + 1, 64),
                      edges=bucket_size(top([len(g.topology.mesh_senders) for g in graphs]), 256),
                      slots=per_union,
                      ball=bucket_size(max(len(g.index.ball_nodes) for g in graphs), 8),
                      panel=bucket_size(max(len(g.index.panel_nodes) for g in graphs), 8),
                      capacity=bucket_size(capacity, 16),
                      pen_ball=bucket_size(max(len(g.pen_ball) for g in graphs), 8),
                      pen_panel=bucket_size(max(len(g.pen_panel) for g in graphs), 8),
                      levels=tuple((bucket_size(per_union * int(n) + 1, 16), bucket_size(per_union * int(e), 16))
                                   for n, e in np.max([level_sizes(g.topology.hierarchy) for g in graphs], axis=0))
                      if graphs[0].topology.hierarchy else ())
