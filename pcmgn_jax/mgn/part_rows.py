"""Per-node stack geometry of each node's own part: the scene features ``own_thickness``, ``layer_depth`` and
``total_thickness`` (:data:`pcmgn_jax.mgn.scene_features.SCENE_FEATURES`; docs/design.md §5, inputs that do not
depend on a layer's index). Host side (NumPy); part ids as in a mesh's ``node_type``: 0 the ball, 1.. the
layers from the top, ``n_parts`` the fixed nodes (the plate's bottom).
"""
from __future__ import annotations

import numpy as np


def geometry_rows(scene: dict, name: str, node_type) -> np.ndarray:
    """(N, 1) float32 [m] per-node stack geometry of each node's own part (ids as in :func:`material_rows`):
    ``own_thickness`` its layer's thickness (0 on the ball), ``layer_depth`` its layer's top surface below the
    contact layer's top (the sum of the thicknesses above it; 0 on the ball and the contact layer),
    ``total_thickness`` the stack's total thickness (every node). None depends on a layer's index, so a
    stack of any layer count gives the same width."""
    thick = [float(layer["thickness"]) for layer in scene.get("layers") or ()]
    if not thick:
        raise ValueError(f"scene feature {name!r}: the scene has no layers")
    if name == "own_thickness":
        table = [0.0] + thick
    elif name == "layer_depth":
        table = [0.0] + list(np.cumsum([0.0] + thick[:-1]))
    elif name == "total_thickness":
        table = [sum(thick)] * (len(thick) + 1)
    else:
        raise ValueError(f"geometry_rows: unknown feature {name!r}")
    table.append(table[-1])  # fixed nodes (node_type == n_parts) lie on the plate's bottom
    node_type = np.asarray(node_type)
    if node_type.size and (node_type.min() < 0 or node_type.max() >= len(table)):
        raise ValueError(f"scene feature {name!r}: node types must lie in 0..{len(table) - 1} for a scene of "
                         f"{len(thick)} layers, got {node_type.min()}..{node_type.max()}")
    return np.asarray(table, np.float32)[node_type][:, None]
