"""Everything derived once from the training split (host side): topology, contact buffer, statistics,
noise levels, loss weights and the penetration boundary.

    setup = prepare(cfg, train_trajs)        # Setup(spec, topology, index, stats, sigma, ...)

The statistics are computed on exactly what the loss sees: the same :func:`pcmgn_jax.train.noise`
draws and target corrections as the training step (the paper's target correction −n/Δt is 7× the
clean x-velocity spread at 0.3 µm noise, so statistics of the clean targets would mis-scale the loss).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple, Sequence

import jax
import numpy as np

from pcmgn_jax.config import TrainConfig
from pcmgn_jax.geometry import roi_boundary_nodes
from pcmgn_jax.mgn import contact as contact_lib
from pcmgn_jax.mgn.checkpoint import make_spec
from pcmgn_jax.mgn.formulation import BALL_PART, Formulation
from pcmgn_jax.mgn.graphs import Topology, build_graph, topology_from_trajectory
from pcmgn_jax.mgn.normalization import Accumulator, Stats, TypedAccumulator, make_stats
from pcmgn_jax.mgn.rollout import Spec
from pcmgn_jax.scene import Scene
from pcmgn_jax.train.noise import motion_rms, noise_parts_mask, noise_sigma, perturb
from pcmgn_jax.train.sampling import pair_table, sample


@dataclass(frozen=True)
class TrainSpec:
    """Static (hashable) training settings: the jit cache key of ``train_chunk``."""

    sim: Spec
    cfg: TrainConfig             # learning rate, lambda_pen, polynomial degrees, ... (one copy)
    decay_steps: int             # resolved lr_decay_steps (0 in the config -> total steps)
    pen_interval: tuple = (0.0, 1.0)  # [m] fixed fit interval of the penetration term


class Setup(NamedTuple):
    spec: TrainSpec
    topology: Topology
    index: contact_lib.ContactIndex
    stats: Stats
    sigma: np.ndarray        # [N] float32 noise std per node [m] (0: not noised)
    pen_nodes: dict          # {"ball": [Mb] int32, "panel": [Mp] int32} boundary nodes of the fits
    weights: dict            # {"motion": [N], "ball": [], "stress": [N]} loss weights, "perturbed": [N] noised parts
    scene: Scene
    n_pairs: int             # (trajectory, frame) training pairs
    total_steps: int


def output_dt(traj) -> float:
    return float(traj.meta.get("output_dt") or (traj.times[1] - traj.times[0]))


def scene_of(traj) -> Scene:
    return Scene.from_dict(traj.meta["scene"])


def total_steps(cfg: TrainConfig, n_pairs: int) -> int:
    steps = cfg.num_steps or int(math.ceil(cfg.epochs * n_pairs / cfg.batch_graphs))
    k = cfg.steps_per_dispatch
    return int(k * math.ceil(steps / k))


def penetration_nodes(cfg: TrainConfig, ref, panel_part: int):
    """Ball-bottom / CG-top node sets and fit interval (:func:`pcmgn_jax.geometry.roi_boundary_nodes`)."""
    return roi_boundary_nodes(ref, panel_part, x_max=cfg.pen_x_max)


def loss_weights(form: Formulation, topology: Topology) -> dict:
    """Per-node loss weights (each channel's weights sum to 1).

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
    return dict(motion=motion.astype(np.float32), ball=np.float32(w_ball),
                stress=spread(np.ones(node_type.shape, bool)).astype(np.float32))


@functools.partial(jax.jit, static_argnames=("spec",))
def _noisy_features(spec: Spec, topology, index, sigma, smp, key):
    form = spec.formulation
    smp = perturb(spec, topology, smp, sigma, key)
    points = smp["points"]
    edges = contact_lib.update(index, points + smp["u"])
    g = build_graph(topology, points=points, displacement=smp["u"], velocity=smp["v"], contact=edges,
                    features=form.features)
    return (g.nodes[:, topology.n_node_types:], g.edges["mesh"].features, g.edges["contact"].features,
            edges.mask, smp["target"], smp["ball"])


def compute_stats(spec: Spec, trajs, topology: Topology, index, sigma, *, max_frames: int = 2000,
                  seed: int = 0) -> Stats:
    """Statistics of the inputs and targets the loss sees (noise and correction included), per node
    type (``per_part``) or over all nodes (``global``); every pair when <= max_frames exist."""
    form = spec.formulation
    pairs = pair_table(trajs)
    if len(pairs) > max_frames:
        pairs = pairs[np.linspace(0, len(pairs) - 1, max_frames).round().astype(int)]
    T = topology.n_node_types
    node_type = np.asarray(topology.node_type)
    n_node = 6 if form.features == "strain" else 4
    acc = dict(node=TypedAccumulator(T, n_node), mesh=TypedAccumulator(T, 6), contact=Accumulator(3),
               motion=TypedAccumulator(T, 2), stress=TypedAccumulator(T, 1), ball=Accumulator(2))
    # motion targets of the free nodes that move on their own (not a rigid ball's), stress of all nodes
    free = ~np.asarray(topology.fixed)
    moving = free & ~((node_type == BALL_PART) & form.rigid_ball)
    recv_type = node_type[np.asarray(topology.mesh_receivers)]
    key = jax.random.PRNGKey(seed)
    f32 = lambda d: {k: np.asarray(v, np.float32) for k, v in d.items()}  # noqa: E731
    for n, (i, t) in enumerate(pairs):
        smp = f32(sample(form, trajs[i], int(t), spec.dt))
        node, mesh, cont, mask, target, ball = _noisy_features(spec, topology, index, sigma, smp,
                                                                jax.random.fold_in(key, n))
        acc["node"].add(node, node_type)
        acc["mesh"].add(mesh, recv_type)
        acc["contact"].add(cont, np.asarray(mask))
        target = np.asarray(target)
        acc["motion"].add(target[:, :2], node_type, moving)
        acc["stress"].add(target[:, 2:], node_type)
        if form.rigid_ball:
            acc["ball"].add(np.asarray(ball)[None])
    return make_stats(**acc, per_part=form.normalization == "per_part", contact_default_std=index.radius)


def prepare(cfg: TrainConfig, train_trajs: Sequence, *, stats_max_frames: int = 2000,
            capacity: int | None = None, radius: float | None = None, stats: Stats | None = None) -> Setup:
    """Topology, contact buffer (sized on all training frames), noise levels, loss weights and the
    normalisation statistics (computed unless ``stats`` is given, e.g. from a checkpoint on resume)."""
    if not train_trajs:
        raise ValueError("no training trajectories")
    ref = train_trajs[0]
    for i, t in enumerate(train_trajs):
        if t.points.shape != ref.points.shape or not np.array_equal(t.cells, ref.cells) or \
                not np.array_equal(t.node_type, ref.node_type):
            raise ValueError(f"training trajectory {i} ({t.meta.get('name', '?')}) has a different topology "
                             "than trajectory 0; one topology per dataset")
    scene = scene_of(ref)
    dt = output_dt(ref)
    topology = topology_from_trajectory(ref)
    ball_part, panel_part = contact_lib.contact_parts(scene)
    r_w = radius or cfg.contact_radius or contact_lib.auto_radius(ref.points, ref.cells, ref.cell_part, panel_part)
    index = contact_lib.allocate(points=ref.points, cells=ref.cells, cell_part=ref.cell_part,
                                 ball_part=ball_part, panel_part=panel_part, radius=r_w,
                                 positions=[t.positions for t in train_trajs],
                                 capacity_factor=cfg.contact_capacity_factor, capacity=capacity)
    sim = make_spec(cfg, dt)
    n_pairs = sum(t.n_frames - 1 for t in train_trajs)
    steps = total_steps(cfg, n_pairs)
    pen_nodes, interval = {"ball": np.zeros(0, np.int32), "panel": np.zeros(0, np.int32)}, (0.0, 1.0)
    if cfg.lambda_pen > 0:
        bn = penetration_nodes(cfg, ref, panel_part)
        interval = tuple(float(v) for v in bn.interval)
        pen_nodes = {"ball": np.asarray(bn.ball, np.int32), "panel": np.asarray(bn.panel, np.int32)}
    spec = TrainSpec(sim=sim, cfg=cfg, decay_steps=cfg.lr_decay_steps or steps, pen_interval=interval)
    rms = motion_rms(train_trajs, topology.node_type, topology.n_node_types) if cfg.noise_rel > 0 else None
    sigma = noise_sigma(topology.node_type, ref.node_part, topology.fixed, parts=cfg.noise_parts,
                        noise_std=cfg.noise_std, noise_rel=cfg.noise_rel, rms=rms)
    if stats is None:
        stats = compute_stats(sim, train_trajs, topology, index, sigma, max_frames=stats_max_frames, seed=cfg.seed)
    weights = dict(loss_weights(sim.formulation, topology),
                   perturbed=noise_parts_mask(ref.node_part, cfg.noise_parts, fixed=topology.fixed).astype(np.float32))
    return Setup(spec, topology, index, stats, sigma, pen_nodes, weights, scene, n_pairs, steps)
