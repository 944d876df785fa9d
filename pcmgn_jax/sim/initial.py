"""The initial state of a drop: the one rule for the solver and for the surrogates' rollouts."""
from __future__ import annotations

import numpy as np

from pcmgn_jax.scene import Scene
from pcmgn_jax.sim.fem import array_module


def initial_velocity(scene: Scene, node_part) -> np.ndarray:
    """Initial nodal velocity (N, 2) [m/s] float64: the ball (node part 0) moves down at the scene's
    drop speed ``scene.ball.velocity`` [m/s], every other node is at rest.

    node_part: (N,) part id of every node (0 = ball)."""
    return ball_velocity(scene.ball.velocity, node_part)


def ball_velocity(speed, node_part):
    """The same rule for a drop speed [m/s] (...) as NumPy or jax (differentiable in the speed): (..., N, 2)."""
    xp = array_module(speed)
    is_ball = np.asarray(node_part) == 0
    vy = xp.where(is_ball, -xp.asarray(speed, float)[..., None], 0.0)
    return xp.stack([xp.zeros_like(vy), vy], axis=-1)
