"""Per-node scene features of the model's inputs (``Formulation.scene_features``; docs/design.md §5): what
each name reads from a scene dict, how many node channels it takes, which channels are normalised over all
nodes, and the (N, k) rows themselves, NumPy or JAX with a traced design (the optimiser differentiates
through the designed layers' thicknesses). Units: SI on the way in (m, Pa, kg m^-3); materials as log10.
"""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from pcmgn_jax.mgn.contact import contact_parts
from pcmgn_jax.mgn.part_rows import geometry_rows
from pcmgn_jax.scene import Scene

SCENE_FEATURES = {"ball_radius": ("ball", "radius"), "ball_velocity": ("ball", "velocity"),  # -> scene dict keys
                  "layer_thickness": ("layers", "thickness"),  # one channel per layer, in the scene's order
                  "stack_thickness": ("layers", "thickness"),  # the same on every node, the contact pair's too
                  "material": ("parts", "material"),  # per node: its own part's material (material_rows)
                  # per node: its own layer's thickness [m] (0 on the ball)
                  "own_thickness": ("parts", "own_thickness"),
                  # per node: its layer's top below the contact layer's top [m]
                  "layer_depth": ("parts", "layer_depth"),
                  "total_thickness": ("parts", "total_thickness")}  # per node: the stack's total thickness [m]
PER_LAYER_FEATURES = ("layer_thickness", "stack_thickness")  # one channel per layer: width = the layer count
LAYER_ONLY_FEATURES = ("layer_thickness",)  # 0 on the contact pair's nodes (scene_feature_rows)
# material_rows: log10(E / 1 Pa), nu, log10(rho / 1 kg m^-3)
MATERIAL_CHANNELS = ("log10_youngs", "poisson", "log10_density")
# constant within a part: normalised over all nodes, never per part
ACROSS_PART_FEATURES = ("material", "own_thickness", "layer_depth")
PART_CHANNELS = {"material": len(MATERIAL_CHANNELS), "own_thickness": 1, "layer_depth": 1, "total_thickness": 1}


def scene_feature_widths(scene: dict, names) -> list[int]:
    """Node channels of each scene feature in ``names``: one per layer (``layer_thickness``, ``stack_thickness``),
    ``len(MATERIAL_CHANNELS)`` (``material``), else 1."""
    widths = {"layers": len(scene.get("layers") or ())}
    return [PART_CHANNELS[n] if SCENE_FEATURES[n][0] == "parts" else widths.get(SCENE_FEATURES[n][0], 1)
            for n in names]


def across_part_channels(scene: dict, names) -> list[int]:
    """Indices, within the scene-feature channels, of those normalised over all nodes even with
    ``per_part`` normalisation (:data:`ACROSS_PART_FEATURES`): a node's own material is one number per
    part, so a per-part normaliser would map it to 0 in every training node and leave the network
    nothing to learn from; across parts it varies (glass, adhesive, polymer, metal)."""
    out, start = [], 0
    for name, width in zip(names, scene_feature_widths(scene, names)):
        if name in ACROSS_PART_FEATURES:
            out += list(range(start, start + width))
        start += width
    return out


def material_rows(scene: dict, node_type) -> np.ndarray:
    """(N, 3) float32 [log10(E / 1 Pa), nu, log10(rho / 1 kg m^-3)] of each node's own part: part 0 the
    ball, 1.. the layers from the top, ``n_parts`` (fixed nodes: the plate's bottom) the last layer.
    Dimensionless and O(1) after the across-part normalisation (:func:`across_part_channels`); the log
    because moduli span 1e7 (OCA) to 2e11 Pa (steel), and a stiffness ratio, not a difference, is what
    a change of material means. Raises ``ValueError`` naming a missing or non-positive property."""
    parts = [("ball", scene.get("ball") or {})] + [(layer.get("name", f"layer {i}"), layer)
                                                    for i, layer in enumerate(scene.get("layers") or ())]
    table = []
    for name, props in parts:
        try:
            e, nu, rho = (float(props[k]) for k in ("youngs", "poisson", "density"))
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"scene feature 'material': part {name!r} needs numbers youngs [Pa], poisson "
                             f"and density [kg/m^3], got {props!r}") from None
        if not (e > 0 and rho > 0 and np.isfinite(nu)):
            raise ValueError(f"scene feature 'material': part {name!r} has youngs={e!r}, density={rho!r} "
                             f"(both must be > 0)")
        table.append((np.log10(e), nu, np.log10(rho)))
    table.append(table[-1])  # fixed nodes (node_type == n_parts) lie on the plate's bottom
    node_type = np.asarray(node_type)
    if node_type.size and (node_type.min() < 0 or node_type.max() >= len(table)):
        raise ValueError(f"scene feature 'material': node types must lie in 0..{len(table) - 1} for a scene of "
                         f"{len(parts) - 1} layers, got {node_type.min()}..{node_type.max()}")
    return np.asarray(table, np.float32)[node_type]


def scene_feature_values(scene: dict, names, design=None):
    """(k,) float32 values [SI] of the scene features ``names`` (:data:`SCENE_FEATURES`) of a scene dict
    (``Scene.to_dict()``, e.g. a trajectory's meta['scene']). ``layer_thickness`` gives one value per
    layer [m]. ``design``: thicknesses (D,) [m] of the scene's ``design_layers`` replacing theirs, NumPy
    or traced JAX (the optimiser differentiates through them); the result is then a JAX array.
    ``material`` is per node, not per scene (:func:`material_rows`)."""
    xp = np if design is None else jnp
    out = []
    for name in names:
        if name not in SCENE_FEATURES:
            raise ValueError(f"scene feature {name!r} must be one of {sorted(SCENE_FEATURES)}")
        group, key = SCENE_FEATURES[name]
        if group == "parts":
            raise ValueError(f"scene feature {name!r} is per node: use scene_feature_rows")
        try:
            if group == "layers":
                designed = list(scene.get("design_layers") or [])
                out.extend(design[designed.index(layer["name"])] if design is not None and layer["name"] in designed
                           else xp.asarray(float(layer[key]), np.float32) for layer in scene[group])
            else:
                out.append(xp.asarray(float(scene[group][key]), np.float32))
        except (KeyError, TypeError):
            raise ValueError(f"scene feature {name!r}: the scene has no {group}.{key}") from None
    return xp.stack([xp.asarray(v, np.float32) for v in out]) if out else xp.zeros((0,), np.float32)


def scene_feature_rows(scene: dict, names, node_type, design=None):
    """(N, k) float32 per-node scene features [SI], in ``names`` order: every node carries its scene's
    :func:`scene_feature_values`, except that the layer-only features (:data:`LAYER_ONLY_FEATURES`) are 0
    on the nodes of the contact pair (the ball and the layer it touches, :func:`pcmgn_jax.mgn.contact.contact_parts`):
    the bodies that touch learn the contact from the contact and their local geometry, and the design is
    stated where the response is read out far from it (the OLED); with them on the ball too, its
    rollout drifts (docs/results/surrogate.md). ``material``: each node's own part's
    (:func:`material_rows`), on every node.
    NumPy, or JAX with a traced ``design`` (see :func:`scene_feature_values`)."""
    xp = np if design is None else jnp
    n = len(node_type)
    blocks = []
    for name in names:
        if name in SCENE_FEATURES and SCENE_FEATURES[name][0] == "parts":
            rows = material_rows(scene, node_type) if name == "material" else geometry_rows(scene, name, node_type)
            blocks.append(xp.asarray(rows))
            continue
        vals = scene_feature_values(scene, (name,), design)
        rows = xp.broadcast_to(vals, (n, vals.shape[0]))
        if name in LAYER_ONLY_FEATURES:
            touching = np.isin(np.asarray(node_type), contact_parts(Scene.from_dict(scene)))
            rows = xp.where(touching[:, None], 0.0, rows)
        blocks.append(rows)
    if not blocks:
        return xp.zeros((n, 0), np.float32)
    return xp.concatenate(blocks, axis=-1).astype(np.float32)
