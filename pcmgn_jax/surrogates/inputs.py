"""What a trajectory gives a surrogate: its design, its scene parameters (checked against training), its parts.

    design_of(t)                                  # (D,) design [m]
    scene_vector(t)                               # (names, values [SI]) of what distinguishes its scene
    ts = TrainingScenes(train_trajs)              # names, x (B, P) [SI], and what training held fixed
    xq = ts.inputs(test_trajs, note)              # (Q, P) [SI]; note(str) records each departure
    xd = ts.rows(designs, note)                   # (Q, P) [SI] of Design objects (data.family.Design)

A trajectory's scene parameters are :func:`scene_vector`'s (``meta['scene_params']`` of a scene
family, else its design). A query missing one of the training parameters raises ValueError naming it.
A :class:`~pcmgn_jax.data.family.Design` (the optimiser's and the explorer's design: a family's row or the
design-layer thicknesses) is asked by its canonical row (:meth:`TrainingScenes.rows`), with the same rules for
missing and unknown parameters; it has no scene, so nothing held fixed is checked. A query whose scene
differs from every training scene in a number training held fixed (any number of ``meta['scene']``: a layer's
thickness or modulus, the ball's density, ...; named 'ball.radius', '<layer>.thickness', '<layer>.youngs',
'half_width', ...) or that carries a scene parameter training did not have is answered as if that number
were unchanged, and ``note`` gets a line naming it.
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from pcmgn_jax.data.family import Design

FIXED_RTOL = 1e-9   # a held-fixed number counts as changed beyond this relative difference


def design_of(traj) -> np.ndarray:
    """(D,) design [m] of a trajectory, in its scene's ``design_layers`` order."""
    d = traj.meta.get("design")
    layers = traj.meta.get("scene", {}).get("design_layers")
    if isinstance(d, dict):
        return np.array([float(d[k]) for k in (layers or d)])
    if d is None:
        raise ValueError(f"trajectory {traj.meta.get('name', '?')}: meta has no 'design'")
    return np.asarray(d, np.float64)


def scene_vector(traj) -> tuple[tuple[str, ...], np.ndarray]:
    """(names, values [SI]) of what distinguishes a trajectory's scene: meta['scene_params'] of a scene
    family (ball radius [m], drop speed [m/s], layer thicknesses [m]), else its design (:func:`design_of`)."""
    params = traj.meta.get("scene_params")
    if params:
        names = tuple(sorted(params))
        return names, np.array([float(params[k]) for k in names])
    layers = tuple(traj.meta.get("scene", {}).get("design_layers") or ())
    return layers, design_of(traj)


def part_names_of(traj) -> tuple[str, ...]:
    """A trajectory's part names (0 the ball, then its layers from the top): meta['part_names'], else its scene's."""
    names = traj.meta.get("part_names")
    if names is None:
        names = ["ball"] + [layer["name"] for layer in (traj.meta.get("scene") or {}).get("layers", ())]
    return tuple(names)


def shared_mesh(trajs) -> bool:
    """True when every trajectory has the same mesh (node count and cells): per-node predictors apply."""
    ref = trajs[0]
    return all(t.n_nodes == ref.n_nodes and np.array_equal(t.cells, ref.cells) for t in trajs)


def trajectory_labels(trajs: Sequence) -> list[str]:
    """Each trajectory's ``meta['name']`` (``trajectory i`` without one), to name it in errors and warnings."""
    return [str(t.meta.get("name", f"trajectory {i}")) for i, t in enumerate(trajs)]


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def scene_numbers(scene: dict) -> dict[str, float]:
    """Every number of a scene dict (``Scene.to_dict()``) by dotted name: top-level fields ('half_width'),
    the ball's ('ball.radius' [m]) and each layer's by its name ('CG.thickness' [m], 'CG.youngs' [Pa])."""
    out = {}
    for k, v in scene.items():
        if k == "layers":
            for layer in v:
                out.update({f"{layer['name']}.{f}": float(x) for f, x in layer.items() if _number(x)})
        elif isinstance(v, dict):
            out.update({f"{k}.{f}": float(x) for f, x in v.items() if _number(x)})
        elif _number(v):
            out[k] = float(v)
    return out


def _number_of(param: str) -> str:
    """The scene number a scene parameter sets: 'ball.radius' itself, a layer name its thickness."""
    return param if "." in param else f"{param}.thickness"


def scene_inputs(trajs: Sequence, names: Sequence[str] | None = None, *,
                 note: Callable[[str], None] | None = None) -> tuple[tuple[str, ...], np.ndarray]:
    """(names, x (B, P) [SI]) of trajectories' scene parameters in ``names`` order (default: the first
    trajectory's). A trajectory lacking one raises ValueError naming it; one with a parameter not in
    ``names`` raises too, unless ``note`` is given (then it is ignored and ``note`` gets a line)."""
    rows = [(label, dict(zip(*scene_vector(t)))) for label, t in zip(trajectory_labels(trajs), trajs)]
    if not rows:
        raise ValueError("scene_inputs: no trajectories")
    names = tuple(rows[0][1]) if names is None else tuple(names)
    return names, _ordered(rows, names, note, "its meta['scene_params']")


def _ordered(rows: Sequence[tuple[str, dict]], names: tuple[str, ...], note: Callable[[str], None] | None,
             where: str) -> np.ndarray:
    """(Q, P) [SI]: each (label, {name: value}) row in ``names`` order; ValueError naming a missing parameter
    (``where``: where it was looked for), or an unknown one unless ``note`` takes a line for it."""
    out = []
    for label, got in rows:
        missing = [n for n in names if n not in got]
        extra = [n for n in got if n not in names]
        if missing or (extra and note is None):
            parts = [f"scene parameter {n!r} missing from {where}" for n in missing]
            parts += [f"scene parameter {n!r} unknown to the model" for n in extra]
            raise ValueError(f"{label}: {'; '.join(parts)} (the model's parameters: {list(names)})")
        for n in extra:
            note(f"{label}: scene parameter {n} = {got[n]:.6g} unknown to the model "
                 f"(not a training parameter): answered as if it were unchanged")
        out.append([got[n] for n in names])
    return np.array(out, np.float64)


class TrainingScenes:
    """The training trajectories' scene parameters (``names``, ``x`` (B, P) [SI]) and ``fixed``
    {scene number: value}: every other number of their ``meta['scene']`` that all of them share."""

    def __init__(self, train_trajs: Sequence):
        self.names, self.x = scene_inputs(train_trajs)
        numbers = [scene_numbers(t.meta.get("scene") or {}) for t in train_trajs]
        set_by_params = {_number_of(n) for n in self.names}
        ref = numbers[0]
        self.fixed = {k: ref[k] for k in sorted(set(ref) - set_by_params)
                      if all(k in n and np.isclose(n[k], ref[k], rtol=FIXED_RTOL, atol=0) for n in numbers)}

    def inputs(self, trajs: Sequence, note: Callable[[str], None]) -> np.ndarray:
        """(Q, P) [SI] scene parameters of query trajectories (module docstring); ``note`` (str) gets a line
        per departure from what training held fixed."""
        _, x = scene_inputs(trajs, self.names, note=note)
        for label, t in zip(trajectory_labels(trajs), trajs):
            numbers = scene_numbers(t.meta.get("scene") or {})
            for k, val in self.fixed.items():
                if k in numbers and not np.isclose(numbers[k], val, rtol=FIXED_RTOL, atol=0):
                    note(f"{label}: {k} = {numbers[k]:.6g} differs from the {val:.6g} held fixed in training: "
                         f"answered as if it were unchanged")
        return x

    def rows(self, designs: Sequence[Design], note: Callable[[str], None]) -> np.ndarray:
        """(Q, P) [SI]: each :class:`~pcmgn_jax.data.family.Design`'s canonical row (a stack's absent layers
        zeroed: :meth:`Design.vector`) in :attr:`names` order (module docstring; ``note`` as :meth:`inputs`)."""
        rows = [(f"design {i}", dict(zip(d.names, d.vector()))) for i, d in enumerate(designs)]
        return _ordered(rows, self.names, note, "the design") if rows else np.zeros((0, len(self.names)))
