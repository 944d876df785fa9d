"""Training-noise injection on input world positions, MeshGraphNets style (DESIGN.md §7, issue 5).

Gaussian noise n ~ N(0, sigma^2) (default sigma = 0.3 µm, per node and per component) is added to the INPUT
world positions of the chosen parts; fixed (clamped) nodes never receive noise. The training target is then
corrected so that the update rule applied to the NOISY input lands exactly on the CLEAN next position, i.e.
the model learns to undo the noise (Pfaff et al. 2021; Sanchez-Gonzalez et al. 2020). With x~_t = x_t + n:

=============  ===================================  ============================  ===========================
target type    target (clean)                       update rule                   corrected target
=============  ===================================  ============================  ===========================
'velocity'     v_{t+1} = (x_{t+1} - x_t) / dt       x_{t+1} = x~_t + v^ dt        v_{t+1} - n / dt
'displacement' Dx = x_{t+1} - x_t                   x_{t+1} = x~_t + Dx^          Dx - n
'position'     x_{t+1}                              x_{t+1} = x^                  x_{t+1} (unchanged)
=============  ===================================  ============================  ===========================

Check: x~_t + (v_{t+1} - n/dt) dt = x_t + n + v_{t+1} dt - n = x_{t+1}. Stress targets are never changed.
Apply the correction in physical units (m/s, m) BEFORE normalising the targets. With a solver velocity
target that is not exactly (x_{t+1} - x_t)/dt the correction still makes the noisy update land where the
clean update lands (x_t + v_{t+1} dt).

Input velocity feature: left UNCHANGED. In MeshGraphNets the velocity feature is derived from the (noisy)
positions, so noise reaches it implicitly; here the velocity is a separate input from the solver, so the
noise acts on the position-dependent features only (world position, mesh-edge x_ij/|x_ij|, contact edges,
which must be built from the noisy positions). :func:`add_position_noise` returns the velocity untouched.

Magnitudes: sigma / dt = 0.3 µm / 4 µs = 0.075 m/s against impact velocities of ~0.6 m/s, so the
velocity-target correction is a sizeable fraction of the target, as intended.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = [
    "NOISE_PARTS",
    "TARGET_TYPES",
    "NoisyInputs",
    "noise_node_mask",
    "sample_position_noise",
    "add_position_noise",
    "correct_target",
]

NOISE_PARTS = ("none", "ball", "panel", "all")
TARGET_TYPES = ("velocity", "displacement", "position")


class NoisyInputs(NamedTuple):
    """positions: (N, 2) noisy world positions [m]; velocity: (N, 2) input velocity, unchanged [m/s] (or
    None); noise: (N, 2) the noise that was added [m] (exactly 0 on un-noised and fixed nodes)."""

    positions: jax.Array
    velocity: jax.Array | None
    noise: jax.Array


def noise_node_mask(node_part, parts: str = "all", *, fixed_mask=None, ball_part: int = 0):
    """(N,) bool: which nodes receive noise.

    node_part: (N,) int part ids (ball_part = the ball, every other id = a panel layer).
    parts:     static 'none' | 'ball' | 'panel' | 'all'.
    fixed_mask: optional (N,) bool of fixed (clamped) nodes; they never receive noise.
    """
    if parts not in NOISE_PARTS:
        raise ValueError(f"noise parts must be one of {NOISE_PARTS}, got {parts!r}")
    node_part = jnp.asarray(node_part)
    if parts == "none":
        mask = jnp.zeros(node_part.shape, bool)
    elif parts == "ball":
        mask = node_part == ball_part
    elif parts == "panel":
        mask = node_part != ball_part
    else:
        mask = jnp.ones(node_part.shape, bool)
    if fixed_mask is not None:
        mask = mask & ~jnp.asarray(fixed_mask, bool)
    return mask


def sample_position_noise(key, node_part, *, sigma: float = 0.3e-6, parts: str = "all", fixed_mask=None,
                          ball_part: int = 0, dtype=jnp.float32):
    """(N, 2) Gaussian noise [m], std ``sigma`` per component on the selected nodes, exactly 0 elsewhere."""
    mask = noise_node_mask(node_part, parts, fixed_mask=fixed_mask, ball_part=ball_part)
    n = sigma * jax.random.normal(key, mask.shape + (2,), dtype)
    return jnp.where(mask[:, None], n, jnp.zeros((), dtype))


def add_position_noise(key, positions, node_part, *, velocity=None, sigma: float = 0.3e-6,
                       parts: str = "all", fixed_mask=None, ball_part: int = 0) -> NoisyInputs:
    """Add Gaussian noise to input world positions (MeshGraphNets-style training noise).

    key:        jax PRNG key.
    positions:  (N, 2) clean world positions x_t [m] (reference + displacement).
    node_part:  (N,) int part ids; ``parts`` selects 'none' | 'ball' | 'panel' | 'all' (static).
    velocity:   optional (N, 2) input velocity [m/s]; returned UNCHANGED (see module docstring).
    sigma:      noise std [m] per component, default 0.3e-6 (0.3 µm, the paper's best).
    fixed_mask: optional (N,) bool; fixed nodes never receive noise.

    Returns NoisyInputs(positions = x_t + n, velocity, noise = n). Build every position-dependent feature
    (mesh-edge x_ij, contact edges) from the noisy positions, and correct the target with
    :func:`correct_target` (same ``noise``). Jittable (parts static); vmappable over keys/frames.
    """
    positions = jnp.asarray(positions)
    dtype = positions.dtype if jnp.issubdtype(positions.dtype, jnp.floating) else jnp.float32
    noise = sample_position_noise(key, node_part, sigma=sigma, parts=parts, fixed_mask=fixed_mask,
                                  ball_part=ball_part, dtype=dtype)
    return NoisyInputs(positions + noise, velocity, noise)


def correct_target(target, noise, target_type: str, *, dt: float | None = None):
    """Target corrected for input-position noise so the update from the noisy input lands on x_{t+1}.

    target:      (N, 2) clean target in physical units: 'velocity' v_{t+1} [m/s] (update x_t + v dt),
                 'displacement' x_{t+1} - x_t [m], 'position' x_{t+1} [m].
    noise:       (N, 2) the noise added to x_t [m] (NoisyInputs.noise).
    target_type: static 'velocity' | 'displacement' | 'position'.
    dt:          frame interval [s]; required for 'velocity'.
    Returns: velocity -> target - noise / dt; displacement -> target - noise; position -> target.
    """
    if target_type not in TARGET_TYPES:
        raise ValueError(f"target_type must be one of {TARGET_TYPES}, got {target_type!r}")
    target = jnp.asarray(target)
    noise = jnp.asarray(noise, target.dtype)
    if target_type == "velocity":
        if dt is None or (isinstance(dt, (int, float)) and not dt > 0):
            raise ValueError(f"correct_target: 'velocity' needs dt > 0, got {dt!r}")
        return target - noise / dt
    if target_type == "displacement":
        return target - noise
    return target
