"""The learned simulator: one jitted step and the ``lax.scan`` rollout.

State of a frame: reference ``points`` (N,2) [m], displacement ``u`` (N,2) [m], velocity ``v`` (N,2) [m/s]
(frame-averaged, (u_t - u_{t-1}) / dt; the solver's at frame 0). World position = points + u; positions are integrated
on the *displacement* so float32 keeps µm steps on mm coordinates. What the model predicts and how it becomes the next
frame is the :class:`~pcmgn_jax.mgn.formulation.Formulation` (targets, rigid ball, normalisation, features).

Boundary conditions re-imposed after every step: fixed nodes (node_type == n_parts) u = v = 0; symmetry-axis nodes
(x = 0) u_x = v_x = 0; with the formulation's ``contact_projection``, cover-glass nodes inside the rigid ball are moved
onto its surface (:func:`project_contact`). Contact edges are recomputed from the predicted positions inside the scan;
every frame reports contact-buffer overflow (callers grow the buffer and re-run).
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from pcmgn_jax import compile_notes
from pcmgn_jax.mgn import contact as contact_lib
from pcmgn_jax.mgn.batching import (
    GraphBatch,
    Layout,
    batch_graphs,
    bucket_size,
    slot_minimums,
    split,
    split_graphs,
    to_union,
)
from pcmgn_jax.mgn.formulation import BALL_PART, Formulation, integrate, model_inputs, rigidify
from pcmgn_jax.mgn.graphs import Topology, build_graph
from pcmgn_jax.mgn.normalization import Stats, denormalize_output, normalize_graph, normalize_last_node_channels
from pcmgn_jax.mgn.stress_target import target_to_stress


@dataclass(frozen=True)
class Spec:
    """Static (hashable) settings of the learned simulator: the jit cache key."""

    model: nn.Module                                         # EncodeProcessDecode
    formulation: Formulation = field(default_factory=Formulation)
    dt: float = 4e-6                                         # frame interval [s]

    def __post_init__(self):
        if not self.dt > 0:
            raise ValueError(f"dt must be > 0 [s], got {self.dt!r}")


class Rollout(NamedTuple):
    displacement: jnp.ndarray  # [T+1, N, 2] m   (frame 0 = initial state)
    velocity: jnp.ndarray      # [T+1, N, 2] m/s
    von_mises: jnp.ndarray     # [T+1, N]    Pa  (frame 0 = the given initial stress)
    overflow: jnp.ndarray      # [T]  bool   contact buffer overflow at the step's input frame
    contact_count: jnp.ndarray  # [T] int32 directed contact edges needed


def ball_mask(topology: Topology):
    return jnp.asarray(topology.node_type) == BALL_PART


def ball_output(topology: Topology, out, layout: Layout | None = None):
    """The rigid ball's normalised output: softmax(score)-weighted mean of the ball nodes' a_x, a_y.

    One graph (``layout`` None): (2,). A disjoint union: (G, 2), the softmax taken over each graph's own
    ball nodes (0 for a graph without any, e.g. padding).
    """
    ball = ball_mask(topology)
    node_graph, n_graph = (jnp.zeros(ball.shape, jnp.int32), 1) if layout is None else layout.segments
    score = jnp.where(ball, out[:, 3], -jnp.inf)
    top = jax.lax.stop_gradient(jax.ops.segment_max(score, node_graph, num_segments=n_graph))
    w = jnp.where(ball, jnp.exp(score - jnp.where(jnp.isfinite(top), top, 0.0)[node_graph]), 0.0)
    total = jax.ops.segment_sum(w, node_graph, num_segments=n_graph)
    pooled = jax.ops.segment_sum(w[:, None] * out[:, :2], node_graph, num_segments=n_graph)
    pooled = pooled / jnp.where(total > 0, total, 1.0)[:, None]
    return pooled[0] if layout is None else pooled


def impose_bc(topology: Topology, field):
    """Zero fixed nodes and the x component on the symmetry axis. field: (N, 2)."""
    field = jnp.where(topology.fixed[:, None], 0.0, field)
    return field.at[:, 0].set(jnp.where(topology.axis, 0.0, field[:, 0]))


X_MARGIN = 1e-9  # [m] round-off margin of the ball's x range in project_contact (1 nm: 4e-5 of a 25 µm element)


def project_contact(index: contact_lib.ContactIndex, points, u):
    """``u`` (N, 2) [m] with the contact layer's top-surface nodes (``index.panel_nodes``) that lie inside
    the ball moved straight down onto the ball's lower surface: the polyline through the ball's
    downward-facing surface nodes (``index.ball_nodes``), interpolated at each node's world x; a node
    outside the ball's x range, or below its surface, is untouched. A hard contact constraint for a
    rigid ball (:class:`~pcmgn_jax.mgn.formulation.Formulation` ``contact_projection``).

    One graph (``index.ball_nodes`` (Nb,)) or a per-graph index of a disjoint union ((G, Nb),
    :func:`pcmgn_jax.mgn.contact.stack`; padded candidates have no allowed pair and are ignored).
    Differentiable almost everywhere (a ``min`` per node), static shapes.
    """
    u = jnp.asarray(u, jnp.float32)
    pos = jnp.asarray(points, jnp.float32) + u

    def one(ball, panel, allowed):
        b_ok, p_ok = jnp.any(allowed, axis=1), jnp.any(allowed, axis=0)
        big = jnp.asarray(1.0, pos.dtype)  # [m] padding sorts last; masked out by the x range below
        xb, yb = jnp.where(b_ok, pos[ball, 0], big), jnp.where(b_ok, pos[ball, 1], big)
        order = jnp.argsort(xb)
        xs, ys = xb[order], yb[order]
        lo, hi = xs[0], jnp.max(jnp.where(b_ok, xb, -big))
        xp, yp = pos[panel, 0], pos[panel, 1]
        surface = jnp.interp(xp, xs, ys)
        # the x range with a round-off margin: an axis node at x = -1e-16 m (a field that is not exactly 0
        # on the symmetry axis, e.g. a regression's) is inside the ball's range, not outside it
        inside = p_ok & (xp >= lo - X_MARGIN) & (xp <= hi + X_MARGIN) & (yp > surface)
        return jnp.where(inside, yp - surface, 0.0)  # how far each panel node must move down [m]

    ball, panel, allowed = (jnp.asarray(a) for a in (index.ball_nodes, index.panel_nodes, index.allowed))
    if ball.ndim == 1:
        depth = one(ball, panel, allowed)
    else:
        depth = jax.vmap(one)(ball, panel, allowed)
    return u.at[panel.reshape(-1), 1].add(-depth.reshape(-1))


_project_frames = jax.jit(jax.vmap(project_contact, in_axes=(None, None, 0)))


def project_frames(index: contact_lib.ContactIndex, points, u) -> np.ndarray:
    """:func:`project_contact` of every frame of ``u`` (T, N, 2) [m] on one mesh (float64 NumPy out): the
    projection applied after a rollout, to a field the scan did not produce whole (a baseline's residual
    plus the baseline, :mod:`pcmgn_jax.surrogates.residual`)."""
    moved = _project_frames(index, jnp.asarray(points, jnp.float32), jnp.asarray(u, jnp.float32))
    return np.asarray(u, np.float64) + (np.asarray(moved, np.float64) - np.asarray(u, np.float32))


# ---- one step -------------------------------------------------------------------------------

def input_graph(form: Formulation, topology: Topology, index: contact_lib.ContactIndex, points, u, v,
                layout: Layout | None = None):
    """The raw (SI) graph the network sees of the state (u, v) (N, 2) [m, m/s], and its contact edges: the one place
    where a state becomes model inputs (:func:`pcmgn_jax.mgn.formulation.model_inputs`, then the contact search and
    :func:`pcmgn_jax.mgn.graphs.build_graph`), for training, statistics and rollouts alike."""
    points = jnp.asarray(points, jnp.float32)
    u_in, v_in, extra = model_inputs(form, ball_mask(topology), jnp.asarray(u, jnp.float32),
                                     jnp.asarray(v, jnp.float32), None if layout is None else layout.segments)
    search = contact_lib.update if layout is None else contact_lib.update_graphs
    edges = search(index, points + u_in)
    graph = build_graph(topology, points=points, displacement=u_in, velocity=v_in, contact=edges,
                        features=form.features, layout=layout, node_extra=extra, identity=form.part_identity,
                        origin=form.origin)
    return graph, edges


def predict(spec: Spec, params, stats: Stats, topology: Topology, index: contact_lib.ContactIndex,
            points, u, v, layout: Layout | None = None):
    """Normalised model output (N, 3) and the contact edges used. Pure; jit/vmap/grad compose.

    ``layout``: None for one graph; for a disjoint union (:mod:`pcmgn_jax.mgn.batching`) the contact
    search runs per graph (``index`` per graph) and the graph carries the padding masks.
    """
    graph, edges = input_graph(spec.formulation, topology, index, points, u, v, layout)
    graph = normalize_graph(stats, graph, topology.node_type)
    return spec.model.apply(params, graph), edges


def network(spec: Spec, params, stats: Stats, topology: Topology, index, points, u0, v0,
            layout: Layout | None = None, *, per_frame: bool = False):
    """``net(u, v) -> (normalised output (N, k), contact edges)``: the network as a function of the state.

    ``processor='per_frame'`` (or ``per_frame=True``): :func:`predict`, the whole network per call.
    ``processor='per_design'``: the graph at the reference (it does not depend on the state, see
    :func:`pcmgn_jax.mgn.formulation.model_inputs`; ``u0``, ``v0`` only give its shapes), the encoder,
    the processor and the decoder's design-only part run here, once; ``net`` then normalises the ball
    state and runs the rest of the decoder (the same network as :func:`predict`, to float round-off).
    """
    form = spec.formulation
    if per_frame or form.processor != "per_design":
        return lambda u, v: predict(spec, params, stats, topology, index, points, u, v, layout)
    graph, edges = input_graph(form, topology, index, points, u0, v0, layout)
    base = spec.model.apply(params, normalize_graph(stats, graph, topology.node_type), method="decoder_base")
    ball, segments = ball_mask(topology), None if layout is None else layout.segments

    def net(u, v):
        _, _, state = model_inputs(form, ball, jnp.asarray(u, jnp.float32), jnp.asarray(v, jnp.float32), segments)
        cond = normalize_last_node_channels(stats, topology.node_type, state)
        return spec.model.apply(params, base, cond, method="decode_from_base"), edges

    return net


def step(spec: Spec, params, stats: Stats, topology: Topology, index, points, u, v, layout: Layout | None = None):
    """One frame forward: (u, v) -> (u_next, v_next, vm_next, contact edges). The whole network per call
    (a reference for the rollout's per-design path)."""
    out, edges = predict(spec, params, stats, topology, index, points, u, v, layout)
    if spec.formulation.panel_model == "quasi_static":
        net = network(spec, params, stats, topology, index, points, u, v, layout, per_frame=True)
        u_next, v_next, vm, _, edges = _advance_quasi_static(spec, stats, topology, index, points, u, v, out, net,
                                                             layout)
        return u_next, v_next, vm, edges
    u_next, v_next, vm = integrate_output(spec, stats, topology, points, u, v, out, layout)
    if spec.formulation.contact_projection:  # the moved nodes' velocity follows their new displacement
        projected = project_contact(index, points, u_next)
        v_next, u_next = impose_bc(topology, v_next + (projected - u_next) / spec.dt), projected
    return u_next, v_next, vm, edges


def _advance_quasi_static(spec: Spec, stats, topology, index, points, u, v, out, net, layout=None, drive=None):
    """A quasi-static panel's frame forward from the output ``out`` at the state (u, v): the ball moves on by its
    acceleration, then the network ``net`` (:func:`network`), evaluated at the ball's new state, gives the panel's
    fields there (the panel's outputs are fields at the input's own time, :func:`formulation.training_sample`). Returns
    (u_next, v_next, vm_next, out_next, edges); a rollout carries ``out_next`` to the next frame, so one evaluation per
    frame (and one for the initial state). ``drive``: None, or the ball's next (u, v) (N, 2) given (its rows are used):
    the ball follows that path instead of the network's acceleration (:func:`rollout_union`'s ``ball_path``)."""
    ball = ball_mask(topology)[:, None]
    ub, vb, _ = integrate_output(spec, stats, topology, points, u, v, out, layout)
    if drive is not None:
        ub, vb = jnp.where(ball, drive[0], ub), jnp.where(ball, drive[1], vb)
    out_next, edges = net(ub, vb)
    up, _, vm = integrate_output(spec, stats, topology, points, ub, vb, out_next, layout)
    u_next = jnp.where(ball, ub, up)
    if spec.formulation.contact_projection:
        u_next = project_contact(index, points, u_next)
    v_next = jnp.where(ball, vb, impose_bc(topology, (u_next - jnp.asarray(u, jnp.float32)) / spec.dt))
    return u_next, v_next, vm, out_next, edges


def integrate_output(spec: Spec, stats: Stats, topology: Topology, points, u, v, out,
                     layout: Layout | None = None):
    """Normalised model output (N, k) -> next (u, v) with boundary conditions, and von Mises (N,) [Pa], >= 0. With a
    ``layout`` (disjoint union) the rigid ball is one body per graph."""
    form = spec.formulation
    phys = denormalize_output(stats, topology.node_type, out)
    a_ball = None
    if form.rigid_ball:
        a_ball = ball_output(topology, out, layout) * stats.ball_std + stats.ball_mean
    u_next, v_next = integrate(form, ball_mask(topology), points=jnp.asarray(points, jnp.float32), u=u, v=v,
                               a=phys[:, :2], a_ball=a_ball, dt=spec.dt,
                               segments=None if layout is None else layout.segments)
    # von Mises [Pa] >= 0: max(output, 0), or the log target's inverse (stress_target)
    return impose_bc(topology, u_next), impose_bc(topology, v_next), target_to_stress(form.stress_target, phys[:, 2])


@functools.partial(jax.jit, static_argnames=("spec",))
def jitted_step(spec: Spec, params, stats, topology, index, points, u, v):
    """``step`` jitted once per spec (for Python-loop rollouts and benchmarks)."""
    return step(spec, params, stats, topology, index, points, u, v)


def _rollout(spec: Spec, n_steps: int, params, stats, topology, index, points, u0, v0, vm0,
             layout: Layout | None = None, ball_path=None):
    points = jnp.asarray(points, jnp.float32)
    quasi_static = spec.formulation.panel_model == "quasi_static"
    if ball_path is not None and not quasi_static:
        raise ValueError("rollout: a given ball path needs the quasi_static panel (its fields are a map of the "
                         "ball's state); a dynamic panel integrates its own state")

    def body(carry, drive):
        u, v, out = carry
        if quasi_static:  # carry the output at (u, v): one network evaluation per frame
            u_next, v_next, vm, out, edges = _advance_quasi_static(spec, stats, topology, index, points,
                                                                   u, v, out, net, layout, drive)
        else:
            u_next, v_next, vm, edges = step(spec, params, stats, topology, index, points, u, v, layout)
        return (u_next, v_next, out), (u_next, v_next, vm, edges.overflow, edges.count)

    u0 = impose_bc(topology, jnp.asarray(u0, jnp.float32))
    v0 = jnp.asarray(v0, jnp.float32)
    if spec.formulation.rigid_ball:
        segments = None if layout is None else layout.segments
        u0, v0 = (rigidify(a, ball_mask(topology), segments) for a in (u0, v0))
    net = network(spec, params, stats, topology, index, points, u0, v0, layout) if quasi_static else None
    out0 = net(u0, v0)[0] if quasi_static else None  # per_design: the processor ran once, in network()
    _, (us, vs, vms, ovf, cnt) = jax.lax.scan(body, (u0, v0, out0), ball_path, length=n_steps)
    cat = lambda a, b: jnp.concatenate([a[None], b], axis=0)  # noqa: E731
    return Rollout(cat(u0, us), cat(v0, vs), cat(jnp.asarray(vm0, jnp.float32), vms), ovf, cnt)


rollout = jax.jit(_rollout, static_argnames=("spec", "n_steps"))
rollout.__doc__ = """Jitted rollout: ``rollout(spec, n_steps, params, stats, topology, index, points, u0, v0, vm0)``.

points (N,2) reference [m]; u0 (N,2) [m], v0 (N,2) [m/s], vm0 (N,) [Pa] the initial frame. Returns :class:`Rollout`
with n_steps + 1 frames. One compilation per (spec, n_steps, shapes)."""


@functools.partial(jax.jit, static_argnames=("spec", "n_steps"))
def rollout_batch(spec: Spec, n_steps: int, params, stats, topology, index, points, u0, v0, vm0):
    """``rollout`` vmapped over a leading design axis of points/u0/v0/vm0 (same topology)."""
    fn = lambda p, u, v, s: _rollout(spec, n_steps, params, stats, topology, index, p, u, v, s)  # noqa
    return jax.vmap(fn)(points, u0, v0, vm0)


@functools.partial(jax.jit, static_argnames=("spec", "n_steps"))
def rollout_union(spec: Spec, n_steps: int, params, stats, batch: GraphBatch, u0, v0, vm0, ball_path=None):
    """``rollout`` of a padded disjoint union of designs (:func:`pcmgn_jax.mgn.batching.batch_graphs`).

    u0, v0 (N, 2), vm0 (N,): the union's initial frame (:func:`pcmgn_jax.mgn.batching.to_union`). ``ball_path``: None
    (the ball moves by the network's acceleration), or (u, v) (n_steps, N, 2) [m, m/s]: the rigid ball's displacement
    and velocity at frames 1..n_steps, given (ball rows used; quasi_static panel only): the panel's fields are then the
    network's map evaluated along that path. Returns :class:`Rollout` over the union's N nodes, with ``overflow`` /
    ``contact_count`` [T, G-1] per graph slot. One compilation per (spec, n_steps, size bucket): another mesh or batch
    in the same bucket reuses it.
    """
    return _rollout(spec, n_steps, params, stats, batch.topology, batch.index, batch.points, u0, v0, vm0,
                    batch.layout, ball_path)


def _until_no_overflow(run, index, max_grow: int):
    """``run(index)`` -> Rollout, growing the contact buffer (outside jit) until nothing overflows."""
    for _ in range(max_grow + 1):
        res = run(index)
        if not bool(np.any(np.asarray(res.overflow))):
            return res, index
        needed = int(np.max(np.asarray(res.contact_count)))
        new = contact_lib.grow(index, needed)  # to a bucket, as batch_graphs rounds (rollout_designs reuses it)
        new = new.replace(capacity=bucket_size(new.capacity, 16))
        if new.capacity == index.capacity:
            break
        index = new
    raise RuntimeError(f"contact buffer overflow persists (capacity {index.capacity}, "
                       f"needed {int(np.max(np.asarray(res.contact_count)))})")


def rollout_checked(spec: Spec, n_steps: int, params, stats, topology, index, points, u0, v0, vm0,
                    *, batched: bool = False, max_grow: int = 6):
    """Rollout that grows the contact buffer (outside jit) and re-runs until nothing overflows.

    ``batched``: the vmap path (:func:`rollout_batch`). Returns (Rollout, index actually used).
    """
    fn = rollout_batch if batched else rollout
    return _until_no_overflow(lambda idx: fn(spec, n_steps, params, stats, topology, idx, points, u0, v0, vm0),
                              index, max_grow)


def rollout_union_checked(spec: Spec, n_steps: int, params, stats, batch: GraphBatch, u0, v0, vm0,
                          *, max_grow: int = 6, ball_path=None):
    """:func:`rollout_union` growing the per-graph contact buffer until nothing overflows.
    Returns (Rollout over the union, the batch actually used)."""
    res, index = _until_no_overflow(
        lambda idx: rollout_union(spec, n_steps, params, stats, batch.replace(index=idx), u0, v0, vm0, ball_path),
        batch.index, max_grow)
    return res, batch.replace(index=index)


def unbatch(batch: GraphBatch, res: Rollout) -> list[Rollout]:
    """A union rollout -> one NumPy :class:`Rollout` per real design (padding dropped)."""
    fields = [split(batch, getattr(res, k), axis=1) for k in ("displacement", "velocity", "von_mises")]
    flags = [split_graphs(batch, getattr(res, k), axis=1) for k in ("overflow", "contact_count")]
    return [Rollout(*parts) for parts in zip(*fields, *flags)]


class DesignRollouts(NamedTuple):
    rollouts: list            # one NumPy Rollout per design, in order
    seconds: float            # wall time of the timed union rollouts [s] (see rollout_designs)
    capacity: int             # contact edges per graph of the last batch (grown if needed)


def rollout_designs(spec: Spec, n_steps: int, params, stats, designs, *, batch_size: int = 8,
                    max_grow: int = 6, compiled: set | None = None, note: str = "the rollout") -> DesignRollouts:
    """Roll out many designs, each on its own mesh, ``batch_size`` at a time as padded disjoint unions.

    designs: sequence of dicts with ``topology``, ``index`` (its ContactIndex), ``points`` (N_g, 2) [m], ``u0``, ``v0``
    (N_g, 2), ``vm0`` (N_g,), and optionally (every design or none) ``ball_u``, ``ball_v`` (n_steps, N_g, 2): a given
    ball path (:func:`rollout_union`'s ``ball_path``). A grown contact buffer (a size bucket) is kept for the following
    batches. Every union of a call has one shape (:func:`pcmgn_jax.mgn.batching.slot_minimums` of
    ``min(batch_size, len(designs))`` slots): a short last batch reuses the full ones' compilation, other design counts
    compile once per power of two. ``compiled``: size buckets (:meth:`GraphBatch.bucket`) already compiled; a batch of a
    new bucket runs once untimed first (compilation, buffer sizing) and its bucket is added. ``seconds`` times the
    rollouts only (host-side batching and splitting excluded). ``note``: the name in the console line printed while a
    new size bucket compiles (:mod:`pcmgn_jax.compile_notes`)."""
    out, capacity, seconds = [], 0, 0.0
    sizes = slot_minimums([d["topology"] for d in designs], min(batch_size, len(designs)))
    for i in range(0, len(designs), batch_size):
        chunk = designs[i:i + batch_size]
        batch = batch_graphs([d["topology"] for d in chunk], [d["index"] for d in chunk],
                             [d["points"] for d in chunk], min_capacity=capacity, **sizes)
        init = [to_union(batch, [d[k] for d in chunk]) for k in ("u0", "v0", "vm0")]
        path = None
        if "ball_u" in chunk[0]:  # (n_steps, N_g, 2) per design -> (n_steps, N, 2) on the union
            path = tuple(np.moveaxis(to_union(batch, [np.moveaxis(np.asarray(d[k]), 0, 1) for d in chunk]), 1, 0)
                         for k in ("ball_u", "ball_v"))
        key = (spec, n_steps, batch.bucket(), path is None)
        if compiled is not None and batch.bucket() not in compiled:
            with compile_notes.first_call(note, key):
                _, batch = rollout_union_checked(spec, n_steps, params, stats, batch, *init, max_grow=max_grow,
                                                 ball_path=path)
            compiled.add(batch.bucket())
        t0 = time.perf_counter()
        with compile_notes.first_call(note, key):
            res, batch = rollout_union_checked(spec, n_steps, params, stats, batch, *init, max_grow=max_grow,
                                               ball_path=path)
            jax.block_until_ready(res)
        seconds += time.perf_counter() - t0
        capacity = batch.index.capacity
        out.extend(unbatch(batch, res))
    return DesignRollouts(out, seconds, capacity)
