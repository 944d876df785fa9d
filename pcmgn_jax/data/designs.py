"""Designs and scene families of a dataset: the default design box, the scene families (the `family`
presets and the panel stacks of :mod:`pcmgn_jax.data.stack`), Latin-hypercube sampling and the parsers of
explicit designs and scene parameters given on a command line. SI throughout (m, m/s)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np

from pcmgn_jax.data.family import Design, Family, family_units
from pcmgn_jax.data.layout import DatasetError
from pcmgn_jax.data.stack import STACK_FAMILIES
from pcmgn_jax.errors import SettingError
from pcmgn_jax.presets import PRESETS
from pcmgn_jax.scene import Scene, with_parameters

DESIGN_LOW = 50e-6                     # default design range [m] (paper: 50-150 µm)
DESIGN_HIGH = 150e-6


@dataclass(frozen=True)
class SceneFamily:
    """Scenes drawn around a base scene: ``parameters`` (name, low, high) in SI, names as in
    :func:`pcmgn_jax.scene.with_parameters` ('ball.radius' [m], 'ball.velocity' [m/s], layer name ->
    thickness [m]); ``n_frames`` overrides the base scene's window (frames of ``output_dt``)."""

    parameters: tuple[tuple[str, float, float], ...]
    n_frames: int = 100
    name: str = "family"
    padded = False                     # a row holds every parameter, each > 0
    plans: ClassVar[tuple[str, ...]] = ()    # one plan: train and test from one hypercube

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p[0] for p in self.parameters)

    @property
    def units(self) -> tuple[str, ...]:
        return family_units(self.names)

    def base(self, scene: Scene) -> Scene:
        """The family's base scene: ``scene`` with the family's window and its layer parameters as the
        design layers (so meta['design'] lists their thicknesses)."""
        import dataclasses as dc
        layers = tuple(n for n in self.names if n in scene.part_names)
        return dc.replace(scene, n_frames=self.n_frames, design_layers=layers)

    def scene(self, base: Scene, params: Mapping[str, float]) -> Scene:
        return with_parameters(base, params)

    def sample(self, n: int, seed: int) -> np.ndarray:
        """(n, P) rows of one seeded Latin hypercube over the family's box [SI] (:func:`lhs_designs`)."""
        lows, highs = (np.array([p[i] for p in self.parameters]) for i in (1, 2))
        return lhs_designs(n, seed=seed, low=lows, high=highs, dim=len(lows))

    def sample_splits(self, n_train: int, n_test: int, seed: int,
                      plan: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(train rows, test rows): the first ``n_train`` and the next ``n_test`` rows of ONE hypercube of
        ``n_train + n_test`` (its rows are in random order); ``plan`` is ignored."""
        rows = self.sample(n_train + n_test, seed)
        return rows[:n_train], rows[n_train:]

    def split_origin(self, seed: int, n_total: int, plan: str | None = None) -> dict[str, Any]:
        return {"kind": "lhs", "seed": int(seed), "n_total": n_total, "parameters": [list(p) for p in self.parameters]}

    def canonical(self, params: Mapping[str, float]) -> dict[str, float]:
        return dict(params)


# The scene family. Ranges around the paper's scene (docs/design.md §2), each chosen to stay in the
# regime the solver is validated for (linear elastic, small strain, Hertz-checked ball sizes and speeds)
# while changing the physics in ways a per-node regression over (T1, T2) cannot follow:
#   ball radius 4-6 mm     the paper's 5 mm +-20 %: ball mass 2.1-7.1 g (x3.4), contact patch and ball
#                          curvature change; the Hertz checks cover 2.5-6 mm
#   drop speed 0.5-0.75 m/s the paper's 0.626 m/s (a 20 mm drop) +-20 %: drop heights 13-29 mm; with the
#                          radius, the impact energy spans 0.26-2.0 mJ around the paper's 0.81 mJ
#   OCA1, OCA2 50-150 µm   the paper's design box
#   POL 30-70 µm           the paper's 50 µm +-40 %: common polarizer film thicknesses
# Thicker OCAs and a heavier, slower ball lengthen the contact: some scenes do not separate inside the
# 400 µs window (evaluation reports the phases each test scene reaches).
FAMILY_PARAMETERS = (("ball.radius", 4.0e-3, 6.0e-3), ("ball.velocity", 0.5, 0.75),
                     ("OCA1", 50e-6, 150e-6), ("OCA2", 50e-6, 150e-6), ("POL", 30e-6, 70e-6))
FAMILIES: dict[str, Family] = {
    **{name: SceneFamily(FAMILY_PARAMETERS, n_frames=p.n_frames, name=name)
       for name, p in PRESETS.items() if p.family == "scene"},
    **STACK_FAMILIES,   # panel stacks of 5-7 layers, a padded parameter vector (pcmgn_jax.data.stack)
}
"""The scene family (a :class:`pcmgn_jax.data.family.Family`) of each family preset (its ``family`` and ``n_frames``
in :data:`pcmgn_jax.presets.PRESETS`)."""


# ---- designs ------------------------------------------------------------------------------------
def lhs_designs(n: int, *, seed: int, low=DESIGN_LOW, high=DESIGN_HIGH, dim: int = 2) -> np.ndarray:
    """(n, dim) float64 Latin-hypercube designs in [low, high]^dim (scipy.stats.qmc, seeded); ``low`` and
    ``high`` are numbers (every dimension) or one bound per dimension (SI: m, or m/s for a speed)."""
    from scipy.stats import qmc

    if not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"lhs_designs: n must be an integer >= 0, got {n!r}")
    lo, hi = (np.broadcast_to(np.asarray(b, np.float64), (dim,)) for b in (low, high))
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(0 < lo) and np.all(lo < hi)):
        raise ValueError(f"lhs_designs: need 0 < low < high, got low={low!r}, high={high!r}")
    if n == 0:
        return np.zeros((0, dim))
    sampler = qmc.LatinHypercube(d=dim, rng=np.random.default_rng(seed))
    return qmc.scale(sampler.random(int(n)), lo, hi).astype(np.float64)


def parse_scene_params(text: str, names: Sequence[str], *, zero_ok: bool = False) -> np.ndarray:
    """Parse ``"ball.radius=3.5e-3,ball.velocity=0.8,OCA1=40e-6,OCA2=160e-6,POL=25e-6;..."`` (SI, scenes
    separated by ';') into (B, len(names)) rows in ``names``' order. ValueError naming the scene and the
    parameter for a missing, unknown, repeated or non-positive value (``zero_ok``: negative; a stack's padded
    row holds 0 for an absent layer)."""
    rows = []
    for i, chunk in enumerate(t for t in text.strip().strip(";").split(";") if t.strip()):
        got: dict[str, float] = {}
        for item in chunk.split(","):
            key, sep, val = (x.strip() for x in item.partition("="))
            if not sep or key not in names or key in got:
                why = "not NAME=VALUE" if not sep else "unknown" if key not in names else "repeated"
                raise SettingError("scene_params", f"scene {i + 1}: {item.strip()!r} is {why} "
                                 f"(parameters: {', '.join(names)}, SI)")
            try:
                got[key] = float(val)
            except ValueError:
                raise SettingError("scene_params", f"scene {i + 1}: {key}={val!r} is not a number") from None
            if not math.isfinite(got[key]) or got[key] < 0 or (got[key] == 0 and not zero_ok):
                raise SettingError("scene_params", f"scene {i + 1}: {key} must be finite and > 0, got {val}")
        if set(got) != set(names):
            raise SettingError("scene_params", f"scene {i + 1} misses {sorted(set(names) - set(got))}")
        rows.append([got[n] for n in names])
    if not rows:
        raise SettingError("scene_params", "empty; expected NAME=VALUE,...;NAME=VALUE,... (SI)")
    return np.asarray(rows, dtype=np.float64)


def parse_designs(text: str, *, dim: int | None = 2) -> np.ndarray:
    """Parse ``"40,40;40,160"`` (µm, designs separated by ';', values by ',') into (B, dim) [m]."""
    if not isinstance(text, str) or not text.strip():
        raise SettingError("designs", "empty; expected e.g. '40,40;40,160' (thicknesses in µm)")
    rows = []
    for i, chunk in enumerate(text.strip().strip(";").split(";")):
        parts = [p.strip() for p in chunk.split(",")]
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            raise SettingError("designs", f"design {i + 1} ({chunk.strip()!r}) is not a list of numbers "
                             "in µm, e.g. '40,160'") from None
        if any(not math.isfinite(v) or v <= 0 for v in vals):
            raise SettingError("designs", f"design {i + 1} ({chunk.strip()!r}) must be finite thicknesses > 0 µm")
        if dim is not None and len(vals) != dim:
            raise SettingError("designs", f"design {i + 1} ({chunk.strip()!r}) has {len(vals)} values, "
                             f"expected {dim}")
        if rows and len(vals) != len(rows[0]):
            raise SettingError("designs", f"design {i + 1} has {len(vals)} values, design 1 has {len(rows[0])}")
        rows.append(vals)
    return np.asarray(rows, dtype=np.float64) * 1e-6


# ---- the splits of a dataset ---------------------------------------------------------------------
@dataclass(frozen=True)
class SplitPlan:
    """One split of a dataset to generate: its ``name``, its ``designs`` (:class:`Design`, rows of ``width``
    values [SI]) and ``origin``, how they were drawn (the manifest's record)."""

    name: str
    designs: tuple[Design, ...]
    origin: dict[str, Any]
    width: int

    @property
    def rows(self) -> np.ndarray:
        """(n, width) float64 [SI]: the designs' values as given."""
        return np.asarray([d.values for d in self.designs], np.float64).reshape(len(self.designs), self.width)


def sampled_splits(scene: Scene, family: Family | None, *, n_train: int, n_test: int, seed: int,
                   low: float = DESIGN_LOW, high: float = DESIGN_HIGH, plan: str | None = None) -> list[SplitPlan]:
    """``train`` and ``test`` of a dataset: the first ``n_train`` and next ``n_test`` rows of one seeded
    hypercube of ``scene``'s design-layer thicknesses over [low, high] [m], or the family's
    :meth:`~pcmgn_jax.data.family.Family.sample_splits` of ``plan`` (None: its first). DatasetError for
    sizes that plan nothing and for an unknown plan."""
    if n_train < 0 or n_test < 0 or n_train + n_test == 0:
        raise DatasetError(f"need n_train + n_test > 0, got n_train={n_train}, n_test={n_test}")
    n_total = n_train + n_test
    if family is None:
        names = scene.design_layers
        rows = lhs_designs(n_total, seed=seed, low=low, high=high, dim=len(names))
        train, test = rows[:n_train], rows[n_train:]
        origin = {"kind": "lhs", "seed": int(seed), "n_total": n_total, "low_m": low, "high_m": high}
    else:
        names, plan = family.names, plan or (family.plans or (None,))[0]
        try:
            train, test = family.sample_splits(n_train, n_test, seed, plan)
        except ValueError as err:
            raise DatasetError(str(err)) from None
        origin = family.split_origin(seed, n_total, plan)
    return [SplitPlan(name, tuple(Design.of(family, r, names) for r in rows), {**origin, "rows": span},
                      len(names))
            for name, rows, span in (("train", train, [0, n_train]), ("test", test, [n_train, n_total]))]


def explicit_split(scene: Scene, family: Family | None, designs, name: str, *, preset: str = "") -> SplitPlan:
    """The split ``name`` of explicit rows ``designs`` (B, P): ``scene``'s design-layer thicknesses [m], or a
    family's parameters (its order, SI; e.g. scenes outside its box, ``experiments.generate --scene_params``)
    on its base scene ``scene``, each scene made once. DatasetError naming a bad shape, value or scene."""
    names = scene.design_layers if family is None else family.names
    designs = np.asarray(designs, dtype=np.float64)
    if designs.ndim != 2 or designs.shape[1] != len(names) or len(designs) == 0:
        raise DatasetError(f"designs must have shape (B>0, {len(names)}) for {list(names)}, got {designs.shape}"
                           + ("" if family is None else f" (preset {preset!r} is a scene family: give its "
                                                        "scene parameters, --scene_params)"))
    padded = family is not None and family.padded
    if not np.all(np.isfinite(designs)) or np.any(designs < 0 if padded else designs <= 0):
        raise DatasetError(f"designs must be finite values > 0 (SI; >= 0 in a stack's padded row) for {list(names)}")
    out = SplitPlan(name, tuple(Design.of(family, r, names) for r in designs), {"kind": "explicit"}, len(names))
    for i, design in enumerate(out.designs if family is not None else ()):    # before the lock
        try:
            design.scene(scene)
        except ValueError as err:
            raise DatasetError(f"scene {i + 1} of {len(designs)}: {err}") from None
    return out


def origin_mismatch(old: dict, n_old: int, new: dict, n_new: int) -> str:
    """Why a split's recorded designs (``old`` origin, ``n_old`` rows) are not the ``n_new`` asked for (``new``
    origin), cause first: '... was generated with plan e1, asked for e2' (plan, kind, seed, count, else bounds)."""
    for key, what in (("plan", "plan"), ("kind", "designs of kind"), ("seed", "seed")):
        if old.get(key) != new.get(key):
            return f"was generated with {what} {old.get(key)}, asked for {new.get(key)}"
    if n_old != n_new:
        return f"holds {n_old} designs, asked for {n_new} (the same {old.get('kind')} seed {old.get('seed')})"
    return f"holds {n_old} other designs (another design box or other explicit designs)"
