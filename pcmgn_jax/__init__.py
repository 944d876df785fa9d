"""pcmgn_jax: physics-constrained MeshGraphNet for ball-drop impact on multi-layer panels."""
from pcmgn_jax.heap import keep_freed_memory

keep_freed_memory()  # before any JAX computation: XLA's per-call scratch buffer stays mapped (heap.py)

from pcmgn_jax.scene import Ball, Layer, Scene, default_scene  # noqa: E402
from pcmgn_jax.trajectory import Trajectory  # noqa: E402

__all__ = ["Ball", "Layer", "Scene", "Trajectory", "default_scene"]
