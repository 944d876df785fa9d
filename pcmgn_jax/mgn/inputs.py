"""Graph inputs of one design: its mesh and scene -> the model's static topology and contact index.

    inp = graph_inputs(mesh, scene, scene_features=names, radius=r_w, capacity=C)   # GraphInputs
    designs = [dict(inp._asdict(), u0=..., v0=..., vm0=...)]     # for mgn.rollout.rollout_designs

``mesh``: anything with reference ``points`` (N, 2) [m], ``cells`` (E, 4), ``cell_part`` (E,) and
``node_type`` (N,) -- a :class:`pcmgn_jax.trajectory.Trajectory` or a ``pcmgn_jax.sim.mesh.Mesh``.
``scene``: a scene dict (``Scene.to_dict()``, a trajectory's ``meta['scene']``) or a
:class:`pcmgn_jax.scene.Scene`. The rule, written once here:

- topology (:func:`pcmgn_jax.mgn.graphs.make_topology`) with n_parts = ball + layers
  (:func:`n_parts_for`), and node types 0..n_parts (n_parts = fixed); with ``identity='role'`` the six role
  types of :data:`pcmgn_jax.mgn.graphs.ROLES` instead, whatever the layer count (the part ids kept in the
  topology's ``node_part`` for the per-node scene features);
- scene features (:func:`with_scene`): the rows (N, k) float32 [SI] of
  :func:`pcmgn_jax.mgn.scene_features.scene_feature_rows` of the design's scene, or none (k = 0);
- contact index (:func:`contact_index`): candidates of the scene's contact pair
  (:func:`pcmgn_jax.mgn.contact.contact_parts`) within r_w [m] (default
  :func:`pcmgn_jax.mgn.contact.auto_radius` of the contact layer, :func:`contact_radius`), a buffer of
  ``capacity`` directed edges, or one sized from ``positions`` (:func:`pcmgn_jax.mgn.contact.allocate`).

All host side (NumPy), except :func:`with_scene` with a traced ``design`` (the optimiser's gradient).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pcmgn_jax.mgn import contact as contact_lib
from pcmgn_jax.mgn.graphs import (
    ROLES,
    Topology,
    make_topology,
    n_parts_of,
    role_types,
    with_scene_features,
)
from pcmgn_jax.mgn.hierarchy import build_levels
from pcmgn_jax.mgn.scene_features import scene_feature_rows
from pcmgn_jax.scene import Scene


class GraphInputs(NamedTuple):
    """The static graph inputs of one design (field names: the design dicts of ``rollout_designs``)."""

    topology: Topology                 # with the scene features (none when no names are asked for)
    index: contact_lib.ContactIndex    # contact candidates, radius r_w [m], capacity C
    points: np.ndarray                 # (N, 2) float32 reference coordinates [m]


def _scene_obj(scene) -> Scene:
    return scene if isinstance(scene, Scene) else Scene.from_dict(scene)


def _scene_dict(scene) -> dict:
    return scene.to_dict() if isinstance(scene, Scene) else scene


def n_parts_for(mesh, scene=None) -> int:
    """Number of parts (ball + layers) of ``mesh``: a trajectory's meta (:func:`pcmgn_jax.mgn.graphs.n_parts_of`),
    else the mesh's ``part_names``, else the scene's parts."""
    if getattr(mesh, "meta", None) is not None:
        return n_parts_of(mesh)
    if getattr(mesh, "part_names", None) is not None:
        return len(mesh.part_names)
    if scene is None:
        raise ValueError("n_parts_for: the mesh names no parts; pass its scene")
    return len(_scene_obj(scene).part_names)


def _part_names(mesh, scene) -> tuple[str, ...]:
    """Part names of ``mesh`` (0 the ball): its meta's or its own ``part_names``, else its scene's."""
    names = (getattr(mesh, "meta", None) or {}).get("part_names") or getattr(mesh, "part_names", None)
    if names is None:
        if scene is None:
            raise ValueError("role node types need the mesh's part names or its scene")
        names = _scene_obj(scene).part_names
    return tuple(names)


def with_scene(topology: Topology, scene, names, design=None) -> Topology:
    """``topology`` with the scene features ``names`` of ``scene`` on its nodes ((N, k) float32 [SI];
    no names: unchanged). ``design`` (D,) [m], possibly traced: the design layers' thicknesses the
    features follow (:func:`pcmgn_jax.mgn.scene_features.scene_feature_rows`)."""
    if not names:
        return topology
    parts = topology.node_type if topology.node_part is None else topology.node_part
    rows = scene_feature_rows(_scene_dict(scene), names, parts, design=design)
    if design is not None:  # traced rows stay JAX arrays (they carry the design's tangent)
        return topology.replace(scene_features=rows)
    return with_scene_features(topology, rows)


def design_topology(mesh, scene=None, scene_features=(), *, n_parts: int | None = None, levels: int = 0,
                    identity: str = "type") -> Topology:
    """The topology of ``mesh`` (n_parts: :func:`n_parts_for`) with the scene features ``scene_features``
    (names, :data:`pcmgn_jax.mgn.scene_features.SCENE_FEATURES`) of ``scene``, (with a scene) its
    contact layer's nodes (``top_nodes``, :func:`pcmgn_jax.mgn.graphs.origin_height`), and ``levels``
    bi-stride coarse levels (``Formulation.hierarchy_levels``; :func:`pcmgn_jax.mgn.hierarchy.build_levels`).
    ``identity``: the formulation's ``part_identity``; 'role' types the nodes by :data:`ROLES` (``n_parts``
    is then the mesh's own, :func:`n_parts_for`)."""
    if identity == "role":
        names = _part_names(mesh, scene)
        topo = make_topology(points=mesh.points, cells=mesh.cells, n_parts=len(ROLES) - 1,
                             node_type=role_types(mesh.node_type, names))
        topo = topo.replace(node_part=np.asarray(mesh.node_type, np.int32))
    else:
        topo = make_topology(points=mesh.points, cells=mesh.cells, node_type=mesh.node_type,
                             n_parts=n_parts_for(mesh, scene) if n_parts is None else n_parts)
    if levels:
        topo = topo.replace(hierarchy=build_levels(topo.mesh_senders, topo.mesh_receivers, topo.n_node, levels))
    if scene is not None:
        _, panel_part = contact_lib.contact_parts(_scene_obj(scene))
        topo = topo.replace(top_nodes=np.asarray(mesh.node_type) == panel_part)
    return with_scene(topo, scene, scene_features)


def topology_from_trajectory(traj, scene_features: tuple = (), levels: int = 0, identity: str = "type") -> Topology:
    """Topology of a :class:`pcmgn_jax.trajectory.Trajectory` (n_parts from its scene/part names), with the
    scene features ``scene_features`` (names, :data:`pcmgn_jax.mgn.scene_features.SCENE_FEATURES`) read from
    its meta['scene'] and ``levels`` coarse levels (:func:`design_topology`)."""
    return design_topology(traj, traj.meta["scene"] if scene_features else traj.meta.get("scene"), scene_features,
                           levels=levels, identity=identity)


def contact_radius(mesh, scene) -> float:
    """Default contact radius r_w [m] of ``mesh``: :func:`pcmgn_jax.mgn.contact.auto_radius` of the
    scene's contact layer."""
    _, panel_part = contact_lib.contact_parts(_scene_obj(scene))
    return contact_lib.auto_radius(mesh.points, mesh.cells, mesh.cell_part, panel_part)


def contact_index(mesh, scene, *, radius: float | None = None, positions=(), capacity_factor: float = 2.0,
                  capacity: int | None = None) -> contact_lib.ContactIndex:
    """Contact candidates of the scene's contact pair on ``mesh`` within ``radius`` [m] (None:
    :func:`contact_radius`); buffer of ``capacity`` directed edges, or sized from ``positions``
    ((T, N, 2) world frames [m]) with ``capacity_factor`` (:func:`pcmgn_jax.mgn.contact.allocate`)."""
    ball_part, panel_part = contact_lib.contact_parts(_scene_obj(scene))
    r_w = contact_radius(mesh, scene) if radius is None else radius
    return contact_lib.allocate(points=mesh.points, cells=mesh.cells, cell_part=mesh.cell_part,
                                ball_part=ball_part, panel_part=panel_part, radius=r_w, positions=positions,
                                capacity_factor=capacity_factor, capacity=capacity)


def graph_inputs(mesh, scene, *, scene_features=(), radius: float | None = None, positions=(),
                 capacity_factor: float = 2.0, capacity: int | None = None,
                 n_parts: int | None = None, levels: int = 0, identity: str = "type") -> GraphInputs:
    """A design's mesh + scene -> :class:`GraphInputs` (topology with its scene features, contact index,
    float32 reference points). See the module docstring for the rule; arguments as in
    :func:`design_topology` and :func:`contact_index`."""
    return GraphInputs(topology=design_topology(mesh, scene, scene_features, n_parts=n_parts, levels=levels,
                                                identity=identity),
                       index=contact_index(mesh, scene, radius=radius, positions=positions,
                                           capacity_factor=capacity_factor, capacity=capacity),
                       points=np.asarray(mesh.points, np.float32))
