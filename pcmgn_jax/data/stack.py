"""The ``stack`` scene family: panel stacks of 5 to 7 layers that no fixed parameter
vector of the paper's scene describes.

    fam = STACK_FAMILIES["stack"]
    train, test = fam.sample_splits(100, 20, seed=0, plan="e2")   # (n, P) padded parameter rows [SI]
    scene = fam.scene(fam.base(default_scene()), dict(zip(fam.names, train[0])))

Every stack is the paper's six layers (CG, OCA1, POL, OCA2, OLED, PLATE) with, at most, one extra film
(``TSP``, a touch-sensor film between POL and OCA2, or ``BF``, a back film under the OLED) and possibly
no polarizer (POL missing): 5, 6 or 7 layers, exactly one OLED (the objective's layer, found by its name).
Each present layer's thickness is drawn uniformly within +-40 % of its nominal value and its Young's
modulus log-uniformly within a factor 2; Poisson's ratio and density are its material class's
(:data:`SLOTS`). The ball's radius and speed are drawn uniformly over :data:`BALL_RANGES`.

The padded parameter vector (:attr:`StackFamily.names`): for every slot of :data:`SLOTS`, in stack order,
``<slot>.thickness`` [m] (0 when absent), ``<slot>.log10_youngs`` [log10 Pa] (the slot's nominal value when
absent, so an absent layer does not stretch the box a response surface scales over) and ``<slot>.present``
(1 or 0); then ``ball.radius`` [m] and ``ball.velocity`` [m/s]. Every scene of the family, of any layer
count, is one such row: it is what the manifest records (``scene_params``), and what kriging, MOP and the
nearest-scene baseline are fitted over.

Split plans (:data:`PLANS`): ``e1`` train and test drawn alike; ``e2`` a held-out layer count (train on
5 and 7 layers, test on 6); ``e3`` an impactor outside the trained range (test balls of radius
:data:`E3_RADIUS`, speeds in range).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar, Mapping, Sequence

import numpy as np

from pcmgn_jax.presets import PRESETS
from pcmgn_jax.scene import Layer, Scene

# slot: (name, material class, nominal thickness [m], nominal E [Pa], nu, density [kg/m^3], kind)
# kind: 'fixed' (every stack), 'pol' (absent in a stack without polarizer), 'extra' (at most one per stack)
SLOTS = (
    ("CG", "glass", 100e-6, 77.0e9, 0.21, 2500.0, "fixed"),
    ("OCA1", "adhesive", 100e-6, 0.01e9, 0.45, 1050.0, "fixed"),
    ("POL", "polymer film", 50e-6, 4.0e9, 0.33, 1300.0, "pol"),
    ("TSP", "polymer film (PET touch sensor)", 50e-6, 4.5e9, 0.38, 1390.0, "extra"),
    ("OCA2", "adhesive", 100e-6, 0.01e9, 0.45, 1050.0, "fixed"),
    ("OLED", "OLED (thin-film stack on polyimide)", 30e-6, 5.15e9, 0.30, 1450.0, "fixed"),
    ("BF", "polymer film (polyimide back film)", 50e-6, 2.5e9, 0.34, 1420.0, "extra"),
    ("PLATE", "metal (aluminium)", 1200e-6, 68.9e9, 0.33, 2700.0, "fixed"),
)
SLOT_NAMES = tuple(s[0] for s in SLOTS)
THICKNESS_SPAN = 0.4            # thickness: nominal x U(1 - 0.4, 1 + 0.4)
MODULUS_FACTOR = 2.0            # Young's modulus: nominal x 2^U(-1, 1) (log-uniform within a factor 2)
BALL_RANGES = (("ball.radius", 3.5e-3, 6.0e-3), ("ball.velocity", 0.45, 0.8))   # [m], [m/s]
E3_RADIUS = (6.5e-3, 7.5e-3)    # (e3) test impactors [m]: larger than any trained ball
OBJECTIVE_LAYER = "OLED"
# the stack variants: (polarizer present, extra film or None) -> layer count 6, 7, 7, 5, 6, 6
VARIANTS = tuple((pol, extra) for pol in (True, False) for extra in (None, "TSP", "BF"))
PLANS = {"e1": ({}, {}), "e2": ({"layer_counts": (5, 7)}, {"layer_counts": (6,)}),
         "e3": ({}, {"radius": E3_RADIUS})}


def variant_layers(pol: bool, extra: str | None) -> tuple[str, ...]:
    """The layer names of a stack variant, top to bottom."""
    return tuple(name for name, *_, kind in SLOTS
                 if kind == "fixed" or (kind == "pol" and pol) or (kind == "extra" and name == extra))


def _names() -> tuple[str, ...]:
    out = []
    for name in SLOT_NAMES:
        out += [f"{name}.thickness", f"{name}.log10_youngs", f"{name}.present"]
    return tuple(out) + tuple(p[0] for p in BALL_RANGES)


@dataclass(frozen=True)
class StackFamily:
    """The stack family: ``n_frames`` frames of the base scene's ``output_dt`` per scene."""

    n_frames: int = 100
    name: str = "stack"
    padded = True                      # an absent layer is a 0 in the row, and the row decides the layers
    plans: ClassVar[tuple[str, ...]] = tuple(PLANS)

    @property
    def names(self) -> tuple[str, ...]:
        """The padded parameter vector's names (module docstring)."""
        return _names()

    @property
    def units(self) -> tuple[str, ...]:
        """'m', 'log10 Pa', '1' (a presence flag) per slot, then 'm', 'm/s' (the ball)."""
        return tuple(unit for _ in SLOTS for unit in ("m", "log10 Pa", "1")) + ("m", "m/s")

    @property
    def parameters(self) -> tuple[tuple[str, float, float], ...]:
        """(name, low, high) of every padded parameter over the family's whole range (an absent layer's
        thickness 0 and flag 0 included where the slot is optional)."""
        out, ranges = [], value_ranges()
        for name, *_, kind in SLOTS:
            (lo_t, hi_t), optional = ranges[f"{name}.thickness"], kind != "fixed"
            out += [(f"{name}.thickness", 0.0 if optional else lo_t, hi_t),
                    (f"{name}.log10_youngs", *ranges[f"{name}.log10_youngs"]),
                    (f"{name}.present", 0.0 if optional else 1.0, 1.0)]
        return tuple(out) + BALL_RANGES

    def base(self, scene: Scene) -> Scene:
        """The family's base scene: ``scene``'s ball, analysis and frame interval, the family's window, no
        design layers (a stack's layers are its scene parameters)."""
        return dataclasses.replace(scene, n_frames=self.n_frames, design_layers=(),
                                   contact_pairs=(("ball", SLOT_NAMES[0]),))

    def scene(self, base: Scene, params: Mapping[str, float]) -> Scene:
        """The scene of a padded parameter row ``params`` ({name: value}, :attr:`names`). ValueError naming
        a missing parameter or a present layer with a non-positive thickness."""
        missing = [n for n in self.names if n not in params]
        if missing:
            raise ValueError(f"stack scene: parameter(s) {missing} missing")
        layers = []
        for name, _, _, _, nu, rho, _ in SLOTS:
            if params[f"{name}.present"] < 0.5:
                continue
            t = float(params[f"{name}.thickness"])
            if not t > 0:
                raise ValueError(f"stack scene: layer {name} is present with thickness {t!r} (must be > 0 m)")
            layers.append(Layer(name, float(10.0 ** params[f"{name}.log10_youngs"]), nu, t, rho))
        ball = dataclasses.replace(base.ball, radius=float(params["ball.radius"]),
                                   velocity=float(params["ball.velocity"]))
        return dataclasses.replace(base, layers=tuple(layers), ball=ball, design_layers=())

    def row(self, variant: tuple[bool, str | None], u: np.ndarray, radius: float, velocity: float) -> np.ndarray:
        """The padded row of ``variant`` from ``u`` (2 per slot, in [0, 1]: thickness, modulus)."""
        present = set(variant_layers(*variant))
        out = []
        for k, (name, _, t0, e0, *_rest) in enumerate(SLOTS):
            if name in present:
                t = t0 * (1 - THICKNESS_SPAN + 2 * THICKNESS_SPAN * u[2 * k])
                out += [t, math.log10(e0) + math.log10(MODULUS_FACTOR) * (2 * u[2 * k + 1] - 1), 1.0]
            else:
                out += [0.0, math.log10(e0), 0.0]
        return np.array(out + [radius, velocity], np.float64)

    def sample(self, n: int, seed: int, *, layer_counts: Sequence[int] = (5, 6, 7),
               radius: tuple[float, float] | None = None,
               velocity: tuple[float, float] | None = None) -> np.ndarray:
        """(n, P) padded rows: a layer count uniform over ``layer_counts``, a variant of that count uniform,
        the continuous numbers from one seeded Latin hypercube (``radius`` / ``velocity`` [m], [m/s]
        override the family's ranges, e.g. for (e3))."""
        from scipy.stats import qmc
        variants = [v for v in VARIANTS if len(variant_layers(*v)) in layer_counts]
        if not variants or n < 0:
            raise ValueError(f"stack sample: no stack of {list(layer_counts)} layers (5, 6 or 7) or n={n} < 0")
        if n == 0:
            return np.zeros((0, len(self.names)))
        rng = np.random.default_rng(seed)
        counts = sorted({len(variant_layers(*v)) for v in variants})
        u = qmc.LatinHypercube(d=2 * len(SLOTS) + 2, rng=rng).random(n)
        (r0, r1), (v0, v1) = radius or BALL_RANGES[0][1:], velocity or BALL_RANGES[1][1:]
        rows = []
        for i in range(n):
            count = counts[int(rng.integers(len(counts)))]
            same = [v for v in variants if len(variant_layers(*v)) == count]
            variant = same[int(rng.integers(len(same)))]
            rows.append(self.row(variant, u[i], r0 + (r1 - r0) * u[i, -2], v0 + (v1 - v0) * u[i, -1]))
        return np.stack(rows)

    def sample_splits(self, n_train: int, n_test: int, seed: int,
                      plan: str | None = "e1") -> tuple[np.ndarray, np.ndarray]:
        """(train rows, test rows) of the split plan ``plan`` (:data:`PLANS`; None: e1); train and test come
        from seeds ``seed`` and ``seed + 1``."""
        plan = plan or "e1"
        if plan not in PLANS:
            raise ValueError(f"stack split plan {plan!r} must be one of {sorted(PLANS)}")
        train_kw, test_kw = PLANS[plan]
        return self.sample(n_train, seed, **train_kw), self.sample(n_test, seed + 1, **test_kw)

    def split_origin(self, seed: int, n_total: int, plan: str | None = "e1") -> dict:
        return {"kind": "stack", "plan": plan or "e1", "seed": int(seed), "n_total": n_total,
                "parameters": [list(p) for p in self.parameters]}

    def canonical(self, params: Mapping[str, float]) -> dict[str, float]:
        """:func:`canonical` of a padded row."""
        return canonical(params)


def value_ranges() -> dict[str, tuple[float, float]]:
    """{name: (low, high)} of every padded number a *present* layer (or the ball) may take in the family
    [SI]: a layer's ``.thickness`` [m] (nominal +-40 %) and ``.log10_youngs`` [log10 Pa] (within a factor 2),
    ``ball.radius`` [m] and ``ball.velocity`` [m/s]. (:attr:`StackFamily.parameters` spans an absent layer's
    0 too.) The ranges :func:`range_warnings` checks and a stack search (``experiments.optimize``) searches."""
    out = {}
    for name, _, t0, e0, *_rest in SLOTS:
        out[f"{name}.thickness"] = (t0 * (1 - THICKNESS_SPAN), t0 * (1 + THICKNESS_SPAN))
        out[f"{name}.log10_youngs"] = (math.log10(e0 / MODULUS_FACTOR), math.log10(e0 * MODULUS_FACTOR))
    return {**out, **{n: (lo, hi) for n, lo, hi in BALL_RANGES}}


def nominal(layers: Sequence[str] = variant_layers(True, None)) -> dict[str, float]:
    """{name: value} of the padded row of the stack ``layers`` (default the paper's six) at every slot's
    nominal thickness [m] and modulus, the ball at the middle of its ranges; an absent slot's flag is 0 but
    its thickness stays nominal (:func:`canonical` zeroes it), so that a page's slider for it starts at a
    layer one can switch on. ValueError naming a layer that is no slot."""
    unknown = [n for n in layers if n not in SLOT_NAMES]
    if unknown:
        raise ValueError(f"stack: layer(s) {unknown} are not slots of the stack family {list(SLOT_NAMES)}")
    out = {}
    for name, _, t0, e0, *_rest in SLOTS:
        out.update({f"{name}.thickness": t0, f"{name}.log10_youngs": math.log10(e0),
                    f"{name}.present": float(name in layers)})
    return {**out, **{n: (lo + hi) / 2 for n, lo, hi in BALL_RANGES}}


def canonical(params: Mapping[str, float]) -> dict[str, float]:
    """The padded row ``params`` ({name: value}) as the family records a scene: each ``.present`` flag
    rounded to 1 (>= 0.5) or 0, an absent slot's thickness 0 and its modulus nominal (module docstring):
    what a response surface fitted on the dataset's rows is asked. Other names pass unchanged."""
    out = dict(params)
    for name, _, _, e0, *_rest in SLOTS:
        flag = f"{name}.present"
        if flag in out:
            out[flag] = float(out[flag] >= 0.5)
            if not out[flag]:
                out.update({f"{name}.thickness": 0.0, f"{name}.log10_youngs": math.log10(e0)})
    return out


def display(name: str) -> tuple[str, str, float] | None:
    """(label, unit, scale) of a padded-row name on a page (value x scale in unit): a layer's thickness in
    µm, its log10 modulus (log10 Pa), its presence flag (1 present, 0 absent); None for the ball's numbers
    and any other name."""
    slot, _, what = name.partition(".")
    if slot not in SLOT_NAMES:
        return None
    return {"thickness": (f"{slot} thickness", "µm", 1e6), "log10_youngs": (f"{slot} modulus", "log10 Pa", 1.0),
            "present": (f"{slot} present (1/0)", "", 1.0)}.get(what)


def stack_layer_count(params: Mapping[str, float]) -> int:
    """The layer count of a padded row ({name: value})."""
    return int(sum(params[f"{name}.present"] >= 0.5 for name in SLOT_NAMES))


def range_warnings(label: str, params: Mapping[str, float]) -> list[str]:
    """Lines naming every number of a stack scene (padded row ``params``) outside the family's ranges: a
    present layer's thickness [m] or log10 modulus, the ball's radius [m] or speed [m/s], and a layer count
    outside 5..7; [] inside. Each line starts ``stack range:`` (metrics.json ``warnings``)."""
    out = []
    for name, (lo, hi) in value_ranges().items():
        slot = name.split(".")[0]
        if slot in SLOT_NAMES and params.get(f"{slot}.present", 0) < 0.5:
            continue
        v = params.get(name)
        if v is not None and not (lo - 1e-9 * abs(lo) <= v <= hi + 1e-9 * abs(hi)):
            out.append(f"stack range: {label}: {name} = {v:.6g} outside the stack family's range "
                       f"[{lo:.6g}, {hi:.6g}]")
    if all(f"{n}.present" in params for n in SLOT_NAMES) and not 5 <= stack_layer_count(params) <= 7:
        out.append(f"stack range: {label}: {stack_layer_count(params)} layers, outside the family's 5 to 7")
    return out


STACK_FAMILIES = {name: StackFamily(n_frames=p.n_frames, name=name)
                  for name, p in PRESETS.items() if p.family == "stack"}


def stack_warnings(trajs: Sequence) -> list[str]:
    """:func:`range_warnings` of every trajectory of a stack family (meta['family'] a :data:`STACK_FAMILIES`
    preset, its padded row in meta['scene_params']), labelled by its meta['name']; [] for other trajectories."""
    out = []
    for i, t in enumerate(trajs):
        if t.meta.get("family") in STACK_FAMILIES and t.meta.get("scene_params"):
            out += range_warnings(str(t.meta.get("name", f"trajectory {i}")), t.meta["scene_params"])
    return out
