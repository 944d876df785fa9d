"""The initial state of a drop: the one rule for the solver and for the surrogates' rollouts."""
from __future__ import annotations

import numpy as np

from pcmgn_jax.scene import Scene


def initial_velocity(scene: Scene, node_part) -> np.ndarray:
    """Initial nodal velocity (N, 2) [m/s] float64: the ball (node part 0) moves down at the scene's
    drop speed ``scene.ball.velocity`` [m/s], every other node is at rest.

    node_part: (N,) part id of every node (0 = ball)."""
    node_part = np.asarray(node_part)
    v0 = np.zeros((node_part.shape[0], 2))
    v0[node_part == 0, 1] = -scene.ball.velocity
    return v0
