"""Named scene parameters as a differentiable map to the solver's mesh and materials.

A parameter is named ``<part>.<field>`` in SI units: a layer's ``thickness`` [m], any part's ``youngs`` [Pa],
``poisson`` [-] or ``density`` [kg/m^3] (parts: ``ball`` and the layers by name), and the ball's ``radius``
[m] and ``velocity`` [m/s, downward]. :class:`ParameterMap` turns a parameter vector theta (P,) (or (B, P))
into the reference coordinates of the full solver mesh, the per-part materials and the drop speed, as NumPy
or jax expressions (differentiable: :mod:`pcmgn_jax.sim.differentiable` takes reverse-mode derivatives
through it).

The coordinates are affine in the geometry parameters (one topology for every value):

- a layer's thickness: the map of :class:`pcmgn_jax.sim.design_map.DesignMap` (measured by finite
  differences of :func:`pcmgn_jax.sim.mesh.build_mesh` and checked affine), here over every named layer on
  the full mesh; the layers' node counts must be fixed by the preset (``MeshSpec.layer_elems``);
- the ball's radius: the ball's mesh scaled about its bottom pole (contact point and gap unchanged). The
  mesh builder itself re-grades the ball for another radius (other node counts), so this derivative is the
  one of the discrete problem on the scaled mesh, the map the finite-difference checks also use.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pcmgn_jax.scene import Scene
from pcmgn_jax.sim import fem
from pcmgn_jax.sim.design_map import DesignMap
from pcmgn_jax.sim.mesh import Mesh, MeshSpec

MATERIAL_FIELDS = ("youngs", "poisson", "density")
BALL_FIELDS = ("radius", "velocity")


def parameter_names(scene: Scene) -> tuple[str, ...]:
    """Every parameter name of ``scene`` (module docstring), layers from the top, then the ball."""
    names = [f"{layer.name}.{f}" for layer in scene.layers for f in ("thickness",) + MATERIAL_FIELDS]
    return tuple(names + [f"ball.{f}" for f in BALL_FIELDS + MATERIAL_FIELDS])


def default_names(scene: Scene) -> tuple[str, ...]:
    """The parameters a gradient reports by default: every layer's thickness and Young's modulus, the
    ball's radius and speed."""
    return tuple([f"{layer.name}.{f}" for layer in scene.layers for f in ("thickness", "youngs")]
                 + ["ball.radius", "ball.velocity"])


def scene_value(scene: Scene, name: str) -> float:
    """The value of parameter ``name`` in ``scene`` [SI]; ValueError naming the known ones."""
    part, _, field = name.partition(".")
    if name not in parameter_names(scene):
        raise ValueError(f"unknown parameter {name!r}; one of {', '.join(parameter_names(scene))}")
    if part == "ball":
        return float(getattr(scene.ball, field))
    return float(getattr({layer.name: layer for layer in scene.layers}[part], field))


def with_values(scene: Scene, values: dict[str, float]) -> Scene:
    """``scene`` with the named parameters set (SI); ValueError for an unknown name."""
    fields: dict[str, dict[str, float]] = {}
    for name, v in values.items():
        scene_value(scene, name)
        part, _, field = name.partition(".")
        fields.setdefault(part, {})[field] = float(v)
    layers = tuple(dataclasses.replace(layer, **fields.get(layer.name, {})) for layer in scene.layers)
    return dataclasses.replace(scene, layers=layers, ball=dataclasses.replace(scene.ball, **fields.get("ball", {})))


@dataclass(frozen=True)
class ParameterMap:
    """theta (..., P) in SI -> the solver's inputs: :meth:`points` (..., N, 2) [m], :meth:`materials`
    (..., n_parts, 3) (youngs [Pa], poisson, density [kg/m^3] per part id, 0 the ball) and :meth:`velocity`
    (...) [m/s]. ``mesh`` is the full solver mesh at ``theta0``; ``jac`` (P, N, 2) [m per unit of the
    parameter] is zero for a non-geometric parameter."""

    names: tuple[str, ...]
    theta0: np.ndarray       # (P,) SI
    mesh: Mesh
    jac: np.ndarray          # (P, N, 2)
    materials0: np.ndarray   # (n_parts, 3)
    velocity0: float         # [m/s]

    @classmethod
    def build(cls, scene: Scene, preset: str | MeshSpec, names=None) -> "ParameterMap":
        """The map of ``names`` (default :func:`default_names`) at ``scene``; ValueError for an unknown name
        or a thickness whose layer's element count follows the thickness (not affine)."""
        names = tuple(default_names(scene) if names is None else names)
        theta0 = np.array([scene_value(scene, n) for n in names])
        layers = [n.partition(".")[0] for n in names if n.endswith(".thickness")]
        dm = DesignMap.build(dataclasses.replace(scene, design_layers=tuple(layers) or scene.design_layers),
                             preset, crop=False)
        mesh = dm.mesh
        jac = np.zeros((len(names), mesh.n_nodes, 2))
        for k, name in enumerate(names):
            if name.endswith(".thickness"):
                jac[k] = dm.jac[layers.index(name.partition(".")[0])]
            elif name == "ball.radius":
                ball = mesh.node_part == 0
                pole = np.array([0.0, mesh.points[ball, 1].min()])
                jac[k, ball] = (mesh.points[ball] - pole) / scene.ball.radius
        parts = [scene.ball] + list(scene.layers)
        materials0 = np.array([[getattr(p, f) for f in MATERIAL_FIELDS] for p in parts], float)
        return cls(names=names, theta0=theta0, mesh=mesh, jac=jac, materials0=materials0,
                   velocity0=float(scene.ball.velocity))

    def theta(self, scene: Scene) -> np.ndarray:
        """(P,) the parameters of ``scene`` (of this map's topology) [SI]."""
        return np.array([scene_value(scene, n) for n in self.names])

    def points(self, theta):
        """Reference coordinates (..., N, 2) [m] at theta (..., P); NumPy or jax."""
        xp = fem.array_module(theta)
        return self.mesh.points + xp.tensordot(theta - self.theta0, self.jac, axes=(-1, 0))

    def materials(self, theta):
        """(..., n_parts, 3): youngs [Pa], poisson, density [kg/m^3] per part id at theta (..., P)."""
        xp = fem.array_module(theta)
        out = xp.broadcast_to(xp.asarray(self.materials0), theta.shape[:-1] + self.materials0.shape)
        names = self.mesh.part_names
        for k, name in enumerate(self.names):
            part, _, field = name.partition(".")
            if field in MATERIAL_FIELDS:
                col = xp.asarray(np.eye(3)[MATERIAL_FIELDS.index(field)])
                row = xp.asarray(np.eye(len(names))[names.index(part)])
                delta = (theta[..., k] - self.theta0[k])[..., None, None] * row[:, None] * col[None, :]
                out = out + delta
        return out

    def velocity(self, theta):
        """The ball's drop speed (...) [m/s] at theta (..., P)."""
        if "ball.velocity" not in self.names:
            return theta[..., 0] * 0.0 + self.velocity0
        return theta[..., self.names.index("ball.velocity")]
