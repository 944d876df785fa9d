"""pcmgn_jax: physics-constrained MeshGraphNet for ball-drop impact on multi-layer panels."""
from pcmgn_jax.scene import Ball, Layer, Scene, default_scene
from pcmgn_jax.trajectory import Trajectory

__all__ = ["Ball", "Layer", "Scene", "Trajectory", "default_scene"]
