"""The impact scene as data: layers, ball, impact, analysis type, output window.

All quantities are SI (m, s, Pa, kg/m^3). A scene is a frozen dataclass that round-trips
through a plain dict, so it can live in a TOML or JSON file (``Scene.load(path)``); a panel
with other layers is a new scene file, not a code change.

Part ids: 0 is the ball, 1..n are the panel layers from top (impacted) to bottom (fixed).
"""
from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

ANALYSES = ("axisymmetric", "plane_strain")


def _check_positive(where: str, name: str, value: float) -> None:
    if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{where}: {name} must be a finite number > 0, got {value!r}")


def _check_nu(where: str, value: float) -> None:
    if not isinstance(value, (int, float)) or not (-1.0 < value < 0.5):
        raise ValueError(f"{where}: poisson (nu) must satisfy -1 < nu < 0.5, got {value!r}")


def _reject_unknown(where: str, data: Mapping[str, Any], allowed: set[str]) -> None:
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")


@dataclass(frozen=True)
class Layer:
    """One bonded panel layer. ``thickness`` [m], ``youngs`` [Pa], ``density`` [kg/m^3]."""

    name: str
    youngs: float
    poisson: float
    thickness: float
    density: float

    def __post_init__(self) -> None:
        where = f"layer {self.name!r}"
        if not self.name or not isinstance(self.name, str):
            raise ValueError(f"layer name must be a non-empty string, got {self.name!r}")
        _check_positive(where, "youngs", self.youngs)
        _check_nu(where, self.poisson)
        _check_positive(where, "thickness", self.thickness)
        _check_positive(where, "density", self.density)


@dataclass(frozen=True)
class Ball:
    """Rigid-free elastic steel ball. ``radius`` [m], ``velocity`` [m/s, downward speed > 0],
    ``gap`` [m] initial clearance above the top layer."""

    radius: float = 5.0e-3
    youngs: float = 200.0e9
    poisson: float = 0.30
    density: float = 7850.0
    velocity: float = 0.62631
    gap: float = 10.0e-6

    def __post_init__(self) -> None:
        _check_positive("ball", "radius", self.radius)
        _check_positive("ball", "youngs", self.youngs)
        _check_nu("ball", self.poisson)
        _check_positive("ball", "density", self.density)
        _check_positive("ball", "velocity", self.velocity)
        if not isinstance(self.gap, (int, float)) or not math.isfinite(self.gap) or self.gap < 0:
            raise ValueError(f"ball: gap must be a finite number >= 0, got {self.gap!r}")

    @property
    def mass_full(self) -> float:
        """Mass of the whole sphere [kg]."""
        return 4.0 / 3.0 * math.pi * self.radius**3 * self.density


def paper_layers(t_oca1: float = 100e-6, t_oca2: float = 100e-6) -> tuple[Layer, ...]:
    """The paper's stack (Table 'Material properties'); densities are assumptions (docs/design.md §2)."""
    return (
        Layer("CG", 77.0e9, 0.21, 100e-6, 2500.0),
        Layer("OCA1", 0.01e9, 0.45, t_oca1, 1050.0),
        Layer("POL", 4.0e9, 0.33, 50e-6, 1300.0),
        Layer("OCA2", 0.01e9, 0.45, t_oca2, 1050.0),
        Layer("OLED", 5.15e9, 0.30, 30e-6, 1450.0),
        Layer("PLATE", 68.9e9, 0.33, 1200e-6, 2700.0),
    )


@dataclass(frozen=True)
class Scene:
    """A ball-drop scene.

    ``half_width`` [m] is the panel's radial (or half) extent; ``output_dt`` [s] the frame
    interval; ``n_frames`` the number of frames written after the initial one.
    ``design_layers`` names the layers whose thicknesses are the design variables.
    ``contact_pairs`` lists the (body, layer) pairs that can touch; only these get contact
    in the solver, contact edges in the graph and the penetration term in the loss.
    """

    layers: tuple[Layer, ...] = field(default_factory=paper_layers)
    ball: Ball = field(default_factory=Ball)
    analysis: str = "axisymmetric"
    half_width: float = 8.0e-3
    output_dt: float = 4.0e-6
    n_frames: int = 100
    design_layers: tuple[str, ...] = ("OCA1", "OCA2")
    contact_pairs: tuple[tuple[str, str], ...] = (("ball", "CG"),)

    def __post_init__(self) -> None:
        if self.analysis not in ANALYSES:
            raise ValueError(f"scene: analysis must be one of {ANALYSES}, got {self.analysis!r}")
        if not self.layers:
            raise ValueError("scene: at least one layer is required")
        names = [layer.name for layer in self.layers]
        if len(set(names)) != len(names):
            raise ValueError(f"scene: layer names must be unique, got {names}")
        if "ball" in names:
            raise ValueError("scene: 'ball' is reserved for the impactor and cannot name a layer")
        _check_positive("scene", "half_width", self.half_width)
        _check_positive("scene", "output_dt", self.output_dt)
        if not isinstance(self.n_frames, int) or self.n_frames < 1:
            raise ValueError(f"scene: n_frames must be an integer >= 1, got {self.n_frames!r}")
        for name in self.design_layers:
            if name not in names:
                raise ValueError(f"scene: design layer {name!r} is missing from layers {names}")
        for pair in self.contact_pairs:
            if len(pair) != 2 or pair[0] != "ball" or pair[1] not in names:
                raise ValueError(
                    f"scene: contact pair {pair!r} must be ('ball', <layer name>) with a layer in {names}")
        if self.contact_pairs and self.contact_pairs[0][1] != names[0]:
            raise ValueError(
                f"scene: the ball can only touch the top layer {names[0]!r}, got {self.contact_pairs[0]!r}")

    # ---- derived -------------------------------------------------------------------------
    @property
    def part_names(self) -> tuple[str, ...]:
        """Part names indexed by part id (0 = ball)."""
        return ("ball",) + tuple(layer.name for layer in self.layers)

    @property
    def panel_thickness(self) -> float:
        return sum(layer.thickness for layer in self.layers)

    @property
    def design(self) -> tuple[float, ...]:
        """Current values of the design variables [m]."""
        by_name = {layer.name: layer for layer in self.layers}
        return tuple(by_name[name].thickness for name in self.design_layers)

    def with_design(self, *thicknesses: float) -> "Scene":
        """The same scene with the design layers' thicknesses [m] replaced."""
        if len(thicknesses) != len(self.design_layers):
            raise ValueError(
                f"scene: expected {len(self.design_layers)} design values for {self.design_layers}, "
                f"got {len(thicknesses)}")
        new = dict(zip(self.design_layers, thicknesses))
        layers = tuple(dataclasses.replace(layer, thickness=float(new[layer.name]))
                       if layer.name in new else layer for layer in self.layers)
        return dataclasses.replace(self, layers=layers)

    # ---- (de)serialisation ---------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "analysis": self.analysis,
            "half_width": self.half_width,
            "output_dt": self.output_dt,
            "n_frames": self.n_frames,
            "design_layers": list(self.design_layers),
            "contact_pairs": [list(p) for p in self.contact_pairs],
            "ball": dataclasses.asdict(self.ball),
            "layers": [dataclasses.asdict(layer) for layer in self.layers],
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, where: str = "scene") -> "Scene":
        if not isinstance(data, Mapping):
            raise ValueError(f"{where}: expected a table/object, got {type(data).__name__}")
        allowed = {f.name for f in dataclasses.fields(cls)}
        _reject_unknown(where, data, allowed)
        kwargs: dict[str, Any] = {k: v for k, v in data.items() if k not in ("layers", "ball")}
        if "layers" in data:
            layer_keys = {f.name for f in dataclasses.fields(Layer)}
            layers = []
            for i, item in enumerate(data["layers"]):
                _reject_unknown(f"{where}: layers[{i}]", item, layer_keys)
                missing = sorted(layer_keys - set(item))
                if missing:
                    raise ValueError(f"{where}: layers[{i}] is missing key(s) {missing}")
                layers.append(Layer(**item))
            kwargs["layers"] = tuple(layers)
        if "ball" in data:
            _reject_unknown(f"{where}: ball", data["ball"], {f.name for f in dataclasses.fields(Ball)})
            kwargs["ball"] = Ball(**data["ball"])
        if "design_layers" in kwargs:
            kwargs["design_layers"] = tuple(kwargs["design_layers"])
        if "contact_pairs" in kwargs:
            kwargs["contact_pairs"] = tuple(tuple(p) for p in kwargs["contact_pairs"])
        try:
            return cls(**kwargs)
        except ValueError as err:
            raise ValueError(f"{where}: {err}") from None

    @classmethod
    def load(cls, path: str | Path) -> "Scene":
        """Load a scene from a ``.toml`` or ``.json`` file (SI units). ValueError naming the file when it is
        missing, not a file, empty (or whitespace / comments only: an empty file is never the default scene)
        or not TOML / JSON."""
        path = Path(path)
        if path.suffix not in (".toml", ".json"):
            raise ValueError(f"{path}: scene files must be .toml or .json")
        if not path.is_file():
            raise ValueError(f"{path}: no such scene file" if not path.exists() else f"{path}: not a file")
        text = path.read_text()
        try:
            data = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text) if text.strip() else {}
        except ValueError as err:   # tomllib.TOMLDecodeError, json.JSONDecodeError
            raise ValueError(f"{path}: not valid {path.suffix[1:].upper()}: {err}") from None
        if not data:
            raise ValueError(f"{path}: empty scene file (no fields); write the scene's fields (docs/design.md §2), or "
                             "leave out --scene for the paper's scene")
        return cls.from_dict(data, where=str(path))


SCENE_PARAMETERS = ("ball.radius", "ball.velocity")
"""Scene parameters besides layer thicknesses: the ball's radius [m] and its downward impact speed [m/s].
Any layer name is a parameter too (that layer's thickness [m]); see :func:`with_parameters`."""


def with_parameters(scene: Scene, params: Mapping[str, float]) -> Scene:
    """The scene with parameters replaced: ``'ball.radius'`` [m], ``'ball.velocity'`` [m/s] (downward speed),
    or a layer name -> that layer's thickness [m]. ValueError naming an unknown parameter."""
    layers = {layer.name: layer for layer in scene.layers}
    ball = {}
    thick = {}
    for name, value in params.items():
        if name in SCENE_PARAMETERS:
            ball[name.split(".", 1)[1]] = float(value)
        elif name in layers:
            thick[name] = float(value)
        else:
            raise ValueError(f"scene parameter {name!r} is unknown; use one of {list(SCENE_PARAMETERS)} or a "
                             f"layer name {list(layers)} (its thickness [m])")
    new_layers = tuple(dataclasses.replace(layer, thickness=thick[layer.name]) if layer.name in thick else layer
                       for layer in scene.layers)
    return dataclasses.replace(scene, layers=new_layers, ball=dataclasses.replace(scene.ball, **ball))


def default_scene(*, t_oca1: float = 100e-6, t_oca2: float = 100e-6, **overrides: Any) -> Scene:
    """The paper's scene with the given OCA thicknesses [m]."""
    return dataclasses.replace(Scene(layers=paper_layers(t_oca1, t_oca2)), **overrides)


PAPER_SCENE_FILE = Path(__file__).parent / "scenes" / "paper_panel.toml"
