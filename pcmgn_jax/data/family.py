"""One idea of a design: the :class:`Family` protocol every scene family implements and the :class:`Design`
that the generator and a dataset's splits pass around. SI throughout (m, m/s, log10 Pa).

    fam = FAMILIES["family_tiny"]                      # a Family (pcmgn_jax.data.designs)
    train, test = fam.sample_splits(4, 2, seed=0)      # (n, P) rows in fam.names' order [SI]
    d = Design.of(fam, train[0])                       # the family, the row of named values
    d.scene(fam.base(default_scene()))                 # its scene (own mesh, own solve)
    d.vector()                                         # (P,) the padded vector a response surface is fitted over
    d.label()                                          # 'ball.radius=4.5 mm, ...'

A design of a dataset without a family (presets ``tiny``, ``cpu``, ``paper``) is a row of design-layer
thicknesses [m] (``Design(None, (("OCA1", t1), ("OCA2", t2)))``), solved in batches on one mesh.

A new scene family is one class with the members of :class:`Family` (a test shows one: it samples, splits,
maps to scenes and generates through :func:`pcmgn_jax.data.dataset.ensure_dataset` ``family=``); the
built-in ones are :class:`pcmgn_jax.data.designs.SceneFamily` (a box of scene parameters) and
:class:`pcmgn_jax.data.stack.StackFamily` (panel stacks of 5-7 layers, a padded row) in
:data:`pcmgn_jax.data.designs.FAMILIES`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from pcmgn_jax.scene import Scene, with_parameters


@runtime_checkable
class Family(Protocol):
    """A scene family: scenes drawn around a base scene, each one a row of named parameters [SI].

    ``name``: the family's preset (trajectories record it as meta['family']); ``n_frames``: frames of the
    base scene's ``output_dt`` per scene; ``padded``: a row is a padded vector (0 stands for an absent part,
    and the row decides the layer list, which a manifest entry records); ``plans``: the split plans
    :meth:`sample_splits` knows, the first the default (() : one plan, ``plan`` ignored)."""

    name: str
    n_frames: int

    @property
    def names(self) -> tuple[str, ...]:
        """The row's parameter names, in order."""
        ...

    @property
    def parameters(self) -> tuple[tuple[str, float, float], ...]:
        """(name, low, high) [SI] of every parameter over the family's range."""
        ...

    @property
    def units(self) -> tuple[str, ...]:
        """The unit of every parameter ('m', 'm/s', 'log10 Pa', '1'), in :attr:`names`' order."""
        ...

    @property
    def padded(self) -> bool:
        ...

    @property
    def plans(self) -> tuple[str, ...]:
        ...

    def base(self, scene: Scene) -> Scene:
        """The family's base scene built on ``scene`` (its window, its design layers)."""
        ...

    def scene(self, base: Scene, params: Mapping[str, float]) -> Scene:
        """The scene of a row ({name: value} [SI]) on the base scene ``base``; ValueError naming a bad value."""
        ...

    def sample(self, n: int, seed: int) -> np.ndarray:
        """(n, P) seeded rows over the family's range [SI]."""
        ...

    def sample_splits(self, n_train: int, n_test: int, seed: int,
                      plan: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(train rows, test rows) of a dataset [SI]; ValueError for an unknown ``plan``."""
        ...

    def split_origin(self, seed: int, n_total: int, plan: str | None = None) -> dict[str, Any]:
        """How :meth:`sample_splits` drew a dataset's rows, as its manifest records it."""
        ...

    def canonical(self, params: Mapping[str, float]) -> dict[str, float]:
        """The row as the family records a scene (a padded row's absent parts zeroed), what a surface is asked."""
        ...


def family_units(names: Sequence[str]) -> tuple[str, ...]:
    """The SI unit of scene parameters named as in :func:`pcmgn_jax.scene.with_parameters` and the stack's
    padded row: 'm/s' for a speed, 'log10 Pa' for a log modulus, '1' for a presence flag, else 'm'."""
    def unit(name: str) -> str:
        what = name.rpartition(".")[2]
        return {"velocity": "m/s", "log10_youngs": "log10 Pa", "present": "1"}.get(what, "m")
    return tuple(unit(n) for n in names)


@dataclass(frozen=True)
class Design:
    """One design: ``family`` (None: the scene's design-layer thicknesses) and ``params``, the row of
    (name, value) pairs [SI] in the family's order (as given: :meth:`vector` is the canonical one)."""

    family: Family | None
    params: tuple[tuple[str, float], ...]

    @classmethod
    def of(cls, family: Family | None, values, names: Sequence[str] | None = None) -> Design:
        """The design of ``values`` (P,) [SI] in ``names``' order (default the family's names)."""
        names = family.names if names is None else names
        return cls(family, tuple((str(n), float(v)) for n, v in zip(names, np.asarray(values, np.float64))))

    @property
    def family_name(self) -> str | None:
        return None if self.family is None else self.family.name

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(n for n, _ in self.params)

    @property
    def values(self) -> tuple[float, ...]:
        """The row's values as given [SI]."""
        return tuple(v for _, v in self.params)

    @property
    def row(self) -> dict[str, float]:
        """{name: value} [SI], in order."""
        return dict(self.params)

    def scene(self, base: Scene) -> Scene:
        """The design's scene on ``base`` (a family's base scene, :meth:`Family.base`; without a family the
        scene whose design layers get these thicknesses)."""
        return with_parameters(base, self.row) if self.family is None else self.family.scene(base, self.row)

    def vector(self) -> np.ndarray:
        """(P,) float64 [SI]: the family's canonical row (:meth:`Family.canonical`) in its order, what a
        response surface over the family is fitted on and asked."""
        row = self.row if self.family is None else self.family.canonical(self.row)
        return np.array([row[n] for n in self.names], np.float64)

    def label(self) -> str:
        """'OCA1=40 µm, OCA2=160 µm' or 'ball.radius=4.5 mm, ball.velocity=0.6 m/s, ...': lengths in mm
        (>= 1 mm) or µm, other values in their SI unit."""
        out = []
        for (name, value), unit in zip(self.params, family_units(self.names)):
            if unit == "m":
                scale, unit = (1e3, "mm") if abs(value) >= 1e-3 else (1e6, "µm")
                value *= scale
            out.append(f"{name}={value:.6g}" + ("" if unit == "1" else f" {unit}"))
        return ", ".join(out)
