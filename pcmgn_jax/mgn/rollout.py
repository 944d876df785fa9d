"""The learned simulator: one jitted step and the ``lax.scan`` rollout.

State of a frame: reference ``points`` (N,2) [m], displacement ``u`` (N,2) [m], velocity ``v`` (N,2)
[m/s] (frame-averaged, (u_t - u_{t-1}) / dt; the solver's at frame 0). World position = points + u;
positions are integrated on the *displacement* so float32 keeps µm steps on mm coordinates. What the
model predicts and how it becomes the next frame is the :class:`~pcmgn_jax.mgn.formulation.Formulation`
(targets, rigid ball, normalisation, features).

Boundary conditions re-imposed after every step: fixed nodes (node_type == n_parts) u = v = 0;
symmetry-axis nodes (x = 0) u_x = v_x = 0. Contact edges are recomputed from the predicted positions
inside the scan; every frame reports contact-buffer overflow (callers grow the buffer and re-run).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from pcmgn_jax.mgn import contact as contact_lib
from pcmgn_jax.mgn.formulation import BALL_PART, Formulation, integrate, rigidify
from pcmgn_jax.mgn.graphs import Topology, build_graph
from pcmgn_jax.mgn.normalization import Stats, denormalize_output, normalize_graph


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


def ball_output(topology: Topology, out):
    """The rigid ball's normalised output (2,): softmax(score)-weighted mean of the ball nodes' a_x, a_y."""
    ball = ball_mask(topology)
    score = jnp.where(ball, out[:, 3], -jnp.inf)
    w = jax.nn.softmax(jnp.where(jnp.any(ball), score, 0.0))
    return jnp.sum(w[:, None] * out[:, :2], axis=0)


def impose_bc(topology: Topology, field):
    """Zero fixed nodes and the x component on the symmetry axis. field: (N, 2)."""
    field = jnp.where(topology.fixed[:, None], 0.0, field)
    return field.at[:, 0].set(jnp.where(topology.axis, 0.0, field[:, 0]))


# ---- one step -------------------------------------------------------------------------------

def predict(spec: Spec, params, stats: Stats, topology: Topology, index: contact_lib.ContactIndex,
            points, u, v):
    """Normalised model output (N, 3) and the contact edges used. Pure; jit/vmap/grad compose."""
    points = jnp.asarray(points, jnp.float32)
    u = jnp.asarray(u, jnp.float32)
    edges = contact_lib.update(index, points + u)
    graph = build_graph(topology, points=points, displacement=u, velocity=v, contact=edges,
                        features=spec.formulation.features)
    graph = normalize_graph(stats, graph, topology.node_type)
    return spec.model.apply(params, graph), edges


def step(spec: Spec, params, stats: Stats, topology: Topology, index, points, u, v):
    """One frame forward: (u, v) -> (u_next, v_next, vm_next, contact edges)."""
    out, edges = predict(spec, params, stats, topology, index, points, u, v)
    u_next, v_next, vm = integrate_output(spec, stats, topology, points, u, v, out)
    return u_next, v_next, vm, edges


def integrate_output(spec: Spec, stats: Stats, topology: Topology, points, u, v, out):
    """Normalised model output (N, k) -> next (u, v) with boundary conditions, and von Mises (N,) [Pa]."""
    form = spec.formulation
    phys = denormalize_output(stats, topology.node_type, out)
    a_ball = None
    if form.rigid_ball:
        a_ball = ball_output(topology, out) * stats.ball_std + stats.ball_mean
    u_next, v_next = integrate(form, ball_mask(topology), points=jnp.asarray(points, jnp.float32), u=u, v=v,
                               a=phys[:, :2], a_ball=a_ball, dt=spec.dt)
    return impose_bc(topology, u_next), impose_bc(topology, v_next), phys[:, 2]


@functools.partial(jax.jit, static_argnames=("spec",))
def jitted_step(spec: Spec, params, stats, topology, index, points, u, v):
    """``step`` jitted once per spec (for Python-loop rollouts and benchmarks)."""
    return step(spec, params, stats, topology, index, points, u, v)


def _rollout(spec: Spec, n_steps: int, params, stats, topology, index, points, u0, v0, vm0):
    points = jnp.asarray(points, jnp.float32)

    def body(carry, _):
        u, v = carry
        u_next, v_next, vm, edges = step(spec, params, stats, topology, index, points, u, v)
        return (u_next, v_next), (u_next, v_next, vm, edges.overflow, edges.count)

    u0 = impose_bc(topology, jnp.asarray(u0, jnp.float32))
    v0 = jnp.asarray(v0, jnp.float32)
    if spec.formulation.rigid_ball:
        u0, v0 = rigidify(u0, ball_mask(topology)), rigidify(v0, ball_mask(topology))
    _, (us, vs, vms, ovf, cnt) = jax.lax.scan(body, (u0, v0), None, length=n_steps)
    cat = lambda a, b: jnp.concatenate([a[None], b], axis=0)  # noqa: E731
    return Rollout(cat(u0, us), cat(v0, vs), cat(jnp.asarray(vm0, jnp.float32), vms), ovf, cnt)


rollout = jax.jit(_rollout, static_argnames=("spec", "n_steps"))
rollout.__doc__ = """Jitted rollout: ``rollout(spec, n_steps, params, stats, topology, index, points, u0, v0, vm0)``.

points (N,2) reference [m]; u0 (N,2) [m], v0 (N,2) [m/s], vm0 (N,) [Pa] the initial frame.
Returns :class:`Rollout` with n_steps + 1 frames. One compilation per (spec, n_steps, shapes).
"""


@functools.partial(jax.jit, static_argnames=("spec", "n_steps"))
def rollout_batch(spec: Spec, n_steps: int, params, stats, topology, index, points, u0, v0, vm0):
    """``rollout`` vmapped over a leading design axis of points/u0/v0/vm0 (same topology)."""
    fn = lambda p, u, v, s: _rollout(spec, n_steps, params, stats, topology, index, p, u, v, s)  # noqa
    return jax.vmap(fn)(points, u0, v0, vm0)


def rollout_checked(spec: Spec, n_steps: int, params, stats, topology, index, points, u0, v0, vm0,
                    *, batched: bool = False, max_grow: int = 6):
    """Rollout that grows the contact buffer (outside jit) and re-runs until nothing overflows.

    Returns (Rollout, index actually used).
    """
    fn = rollout_batch if batched else rollout
    for _ in range(max_grow + 1):
        res = fn(spec, n_steps, params, stats, topology, index, points, u0, v0, vm0)
        if not bool(np.any(np.asarray(res.overflow))):
            return res, index
        needed = int(np.max(np.asarray(res.contact_count)))
        new = contact_lib.grow(index, needed)
        if new.capacity == index.capacity:
            break
        index = new
    raise RuntimeError(f"contact buffer overflow persists (capacity {index.capacity}, "
                       f"needed {int(np.max(np.asarray(res.contact_count)))})")
