"""Designs that are rows of scene parameters, each answered on its own mesh: the design of a row, its query
trajectory, the solver at it, and the search box of a panel-stack run (shared by the explorer
and ``experiments.optimize``).

    fam = family_of(ref)                              # the run's scene family (None: a design-layer run)
    d = design_at(names, x, fam)                      # a data.family.Design; a family's row made canonical
    scene = d.scene(scene0)                           # the scene of that design on a training scene
    q = query(d, scene0, ref, preset)                 # its mesh and initial state as a trajectory
    box = stack_box(layers=("CG", ...), search=None)  # a stack search: names, bounds, the fixed base row
    box.design(x, fam)                                # the Design of searched values x (D,) [SI]

A stack's row (:mod:`pcmgn_jax.data.stack`) decides its layer list (the ``.present`` flags), so every row
builds its own mesh: no design map, no gradient through the mesh. What a row means, its names and their
ranges live in :mod:`pcmgn_jax.data.stack`; this module only assembles them.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from pcmgn_jax.data.designs import FAMILIES
from pcmgn_jax.data.family import Design
from pcmgn_jax.data.stack import (
    SLOT_NAMES,
    VARIANTS,
    StackFamily,
    canonical,
    nominal,
    value_ranges,
    variant_layers,
)
from pcmgn_jax.scene import Scene
from pcmgn_jax.sim.initial import initial_velocity
from pcmgn_jax.sim.mesh import build_mesh, roi
from pcmgn_jax.sim.output import to_trajectories
from pcmgn_jax.sim.solver import simulate
from pcmgn_jax.trajectory import Trajectory

PAPER_STACK = variant_layers(True, None)   # the paper's six layers: the stack search's default layer list


def family_of(traj):
    """The scene family of a trajectory (its meta['family'], a preset of :data:`FAMILIES`), else None."""
    return FAMILIES.get(traj.meta.get("family") or "")


def is_stack(family) -> bool:
    """True for the panel-stack family: its search box and page are built from the stack's slots
    (:func:`stack_box`), which no other family has; everything else goes through the Family protocol."""
    return isinstance(family, StackFamily)


def design_at(names: Sequence[str], x, family=None) -> Design:
    """The :class:`~pcmgn_jax.data.family.Design` of parameter values x (P,) [SI] in ``names``' order; for a family
    its canonical row (:meth:`pcmgn_jax.data.family.Family.canonical`; a stack's: flags 0/1, an absent layer's
    thickness 0). Its scene is ``.scene(scene0)`` on a training scene of the run (ValueError naming a bad
    parameter, e.g. a present layer of thickness 0)."""
    row = {n: float(v) for n, v in zip(names, np.asarray(x, float).reshape(-1))}
    return Design(family, tuple((row if family is None else family.canonical(row)).items()))


def query(design: Design, scene0: Scene, ref: Trajectory, preset: str | None, *, name: str = "the explored design",
          record: bool | None = None) -> Trajectory:
    """``design``'s scene on ``scene0`` as a trajectory holding only its initial state (the solver's rule,
    :func:`pcmgn_jax.sim.initial.initial_velocity`) on its own mesh (``preset``, cropped to its region of
    interest; None: ``ref``'s mesh), ``ref``'s frame times: what a predictor is asked. ``record`` (default:
    the design has a family): its row goes to meta['scene_params'], where the response surfaces read it."""
    scene = design.scene(scene0)
    if preset is None:
        mesh = ref
    else:
        mesh, _ = roi(build_mesh(scene, preset), preset)
    T, N = ref.n_frames, len(mesh.points)
    v = np.zeros((T, N, 2))
    v[0] = initial_velocity(scene, mesh.node_part)
    meta = {"scene": scene.to_dict(), "part_names": list(scene.part_names), "name": name,
            "design": {n: float(t) for n, t in zip(scene.design_layers, scene.design)}}
    if design.family is not None if record is None else record:
        meta["scene_params"] = design.row
    return Trajectory(points=np.asarray(mesh.points, np.float64), cells=mesh.cells, cell_part=mesh.cell_part,
                      node_part=mesh.node_part, node_type=mesh.node_type, times=np.asarray(ref.times),
                      displacement=np.zeros((T, N, 2)), velocity=v, von_mises=np.zeros((T, N)), meta=meta)


def solve_scene(scene: Scene, preset: str):
    """(ROI-cropped trajectory, the solver's result) of ``scene`` by the built-in solver at ``preset``."""
    result = simulate([scene], preset)
    (traj,) = to_trajectories(result, [scene], preset)
    return traj, result


@dataclass(frozen=True)
class ParameterBox:
    """A search box of named scene parameters: ``low`` / ``high`` (D,) [SI], no constraint beyond the
    bounds; the interface of :class:`pcmgn_jax.opt.problem.DesignBox` that :func:`pcmgn_jax.opt.search.ga`
    uses. ``base``: the full row ({name: value} [SI]) the searched values are set into."""

    names: tuple[str, ...]
    low: np.ndarray
    high: np.ndarray
    base: Mapping[str, float]
    n_constraints: int = 0

    @property
    def dim(self) -> int:
        return len(self.names)

    def constraints(self, designs) -> np.ndarray:
        return np.zeros((len(np.atleast_2d(designs)), 0))

    def violation(self, designs) -> np.ndarray:
        d = np.atleast_2d(np.asarray(designs, float))
        return np.maximum(0.0, np.maximum(self.low - d, d - self.high).max(axis=1))

    def project(self, designs) -> np.ndarray:
        return np.clip(np.atleast_2d(np.asarray(designs, float)), self.low, self.high)

    def starts(self, n: int, seed: int = 0) -> np.ndarray:
        from scipy.stats import qmc
        z = qmc.LatinHypercube(d=self.dim, rng=np.random.default_rng(seed)).random(n)
        return self.low + z * (self.high - self.low)

    def row(self, x) -> dict[str, float]:
        """The full row of searched values x (D,) [SI] set into :attr:`base`."""
        return canonical({**self.base, **dict(zip(self.names, map(float, np.asarray(x, float))))})

    def design(self, x, family) -> Design:
        """The :class:`~pcmgn_jax.data.family.Design` of ``family`` (the run's) at searched values x (D,) [SI]."""
        return Design(family, tuple(self.row(x).items()))


def stack_box(layers: Sequence[str] = PAPER_STACK, search: Sequence[str] | None = None) -> ParameterBox:
    """The search box of a stack of ``layers`` (top to bottom, slots of :data:`pcmgn_jax.data.stack.SLOTS`):
    the parameters ``search`` (default: every layer's thickness [m] and log10 modulus [log10 Pa]; the ball's
    ``ball.radius`` / ``ball.velocity`` only when named: an impactor is a test condition, not a design) over
    the family's ranges (:func:`pcmgn_jax.data.stack.value_ranges`), the rest held at the stack's nominal row
    (:func:`pcmgn_jax.data.stack.nominal`: nominal layers, the ball at the middle of its ranges). ValueError
    naming an unknown parameter, a layer not in the stack, a presence flag (the layer list is chosen by
    ``layers``, not searched) or a layer list outside the family."""
    layers = tuple(layers)
    family = [variant_layers(pol, extra) for pol, extra in VARIANTS]
    if layers not in family:
        raise ValueError(f"stack: the layers {list(layers)} are no stack of the family ({_why_not(layers)}); "
                         "its stacks: " + "; ".join(",".join(v) for v in family))
    base = canonical(nominal(layers))
    ranges = value_ranges()
    allowed = [n for n in ranges if n.split(".")[0] in layers or n.startswith("ball.")]
    names = tuple(search) if search else tuple(n for n in allowed if not n.startswith("ball."))
    bad = [n for n in names if n not in allowed]
    if bad:
        def why(name: str) -> str:
            slot, _, what = name.partition(".")
            if slot in SLOT_NAMES and what == "present":
                return "a presence flag: choose the layer list (--stack) instead"
            if f"{slot}.{what}" in ranges and slot not in layers:
                return f"layer {slot} is not in the stack {list(layers)}"
            return "unknown"
        why = {n: why(n) for n in bad}
        raise ValueError("stack search: cannot search " + "; ".join(f"{n!r} ({w})" for n, w in why.items())
                         + f". Searchable for this stack: {', '.join(allowed)}")
    if len(set(names)) != len(names):
        raise ValueError(f"stack search: a parameter is named twice in {list(names)}")
    low, high = (np.array([ranges[n][i] for n in names]) for i in (0, 1))
    return ParameterBox(names, low, high, base)


def _why_not(layers: Sequence[str]) -> str:
    """The first rule of the stack family that ``layers`` breaks (:data:`pcmgn_jax.data.stack.VARIANTS`)."""
    unknown = [n for n in layers if n not in SLOT_NAMES]
    if unknown:
        return f"unknown layer(s) {unknown}"
    if len(set(layers)) != len(layers) or list(layers) != [n for n in SLOT_NAMES if n in layers]:
        return f"each layer once, in the order {list(SLOT_NAMES)}"
    if not 5 <= len(layers) <= 7:
        return f"{len(layers)} layers; the family's stacks have 5 to 7"
    missing = [n for n in variant_layers(False, None) if n not in layers]
    if missing:
        return f"without {', '.join(missing)}: every stack has the contact layer CG, OCA1, OCA2, the OLED and PLATE"
    return "at most one extra film (TSP or BF)"


def parse_names(text: str) -> tuple[str, ...]:
    """'A,B' -> ('A', 'B') (blanks dropped)."""
    return tuple(s.strip() for s in text.split(",") if s.strip())
