"""Scene: validation messages name the field and the value; TOML/JSON round trips; designs."""
from __future__ import annotations

import copy
import json
import re

import pytest

from pcmgn_jax.scene import Ball, Layer, Scene, default_scene, paper_layers


def _dict(**top):
    d = default_scene().to_dict()
    d.update(top)
    return d


def _with_layer(i, **changes):
    d = default_scene().to_dict()
    d["layers"][i].update(changes)
    return d


def _raises(data, *fragments):
    with pytest.raises(ValueError) as info:
        Scene.from_dict(data)
    msg = str(info.value)
    for frag in fragments:
        assert frag in msg, f"{frag!r} not in {msg!r}"
    return msg


# ---- bad input ---------------------------------------------------------------------------------
@pytest.mark.parametrize("value", [-50e-6, 0.0, 0])
def test_bad_thickness_names_layer_field_value(value):
    _raises(_with_layer(1, thickness=value), "OCA1", "thickness", repr(value))


@pytest.mark.parametrize("value", [0.5, 0.6, -1.0])
def test_bad_poisson(value):
    _raises(_with_layer(0, poisson=value), "CG", "poisson", repr(value))


@pytest.mark.parametrize("value", [0.0, -77e9])
def test_bad_youngs(value):
    _raises(_with_layer(0, youngs=value), "CG", "youngs", repr(value))


def test_bad_ball_values():
    d = _dict()
    d["ball"]["poisson"] = 0.5
    _raises(d, "ball", "poisson", "0.5")
    d = _dict()
    d["ball"]["youngs"] = -1.0
    _raises(d, "ball", "youngs", "-1.0")
    d = _dict()
    d["ball"]["radius"] = 0.0
    _raises(d, "ball", "radius", "0.0")
    d = _dict()
    d["ball"]["gap"] = -1e-6
    _raises(d, "ball", "gap", "-1e-06")


def test_non_numeric_and_non_finite_values():
    _raises(_with_layer(2, thickness="50um"), "POL", "thickness", "'50um'")
    _raises(_with_layer(2, youngs=float("nan")), "POL", "youngs", "nan")
    _raises(_with_layer(2, density=float("inf")), "POL", "density", "inf")


def test_bad_top_level_values():
    _raises(_dict(analysis="plane_stress"), "analysis", "'plane_stress'")
    _raises(_dict(half_width=-1e-3), "half_width", "-0.001")
    _raises(_dict(output_dt=0.0), "output_dt", "0.0")
    _raises(_dict(n_frames=0), "n_frames", "0")


def test_unknown_keys_named():
    _raises(_dict(foo=1), "unknown key", "'foo'")
    _raises(_with_layer(3, colour="red"), "layers[3]", "unknown key", "'colour'")
    d = _dict()
    d["ball"]["spin"] = 3.0
    _raises(d, "ball", "unknown key", "'spin'")


def test_missing_layer_key_named():
    d = default_scene().to_dict()
    del d["layers"][4]["density"]
    _raises(d, "layers[4]", "missing", "'density'")


def test_missing_design_layer_named():
    d = default_scene().to_dict()
    d["layers"] = [layer for layer in d["layers"] if layer["name"] != "OCA2"]
    _raises(d, "design layer", "'OCA2'")
    _raises(_dict(design_layers=["OCA1", "OCA9"]), "design layer", "'OCA9'")


def test_empty_or_duplicate_layers():
    _raises(_dict(layers=[]), "layer")
    d = default_scene().to_dict()
    d["layers"][2]["name"] = "CG"
    _raises(d, "unique", "'CG'")


def test_contact_pair_must_name_top_layer():
    _raises(_dict(contact_pairs=[["ball", "OLED"]]), "top layer", "'CG'")
    _raises(_dict(contact_pairs=[["ball", "NOPE"]]), "contact pair", "NOPE")


def test_direct_construction_validates_too():
    with pytest.raises(ValueError, match=r"thickness.*-1e-05"):
        Layer("X", 1e9, 0.3, -1e-5, 1000.0)
    with pytest.raises(ValueError, match=r"poisson.*0\.5"):
        Ball(poisson=0.5)
    with pytest.raises(ValueError, match="n_frames"):
        Scene(n_frames=2.5)


def test_error_names_the_file(tmp_path):
    # scene-level errors are prefixed with the file (layer/ball errors name the layer/ball only)
    d = _dict(n_frames=0)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=re.escape(str(path))):
        Scene.load(path)
    other = tmp_path / "scene.yaml"
    other.write_text("{}")
    with pytest.raises(ValueError, match="toml"):
        Scene.load(other)


# ---- round trips --------------------------------------------------------------------------------
def _toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v) if isinstance(v, int) else repr(float(v))
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(v)


def _to_toml(d: dict) -> str:
    """Minimal TOML writer for a scene dict (no third-party writer is a dependency)."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in d.items() if k not in ("ball", "layers")]
    lines.append("\n[ball]")
    lines += [f"{k} = {_toml_value(v)}" for k, v in d["ball"].items()]
    for layer in d["layers"]:
        lines.append("\n[[layers]]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in layer.items()]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("analysis", ["axisymmetric", "plane_strain"])
def test_json_round_trip(tmp_path, analysis):
    scene = default_scene(t_oca1=70e-6, t_oca2=130e-6, analysis=analysis, n_frames=150)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene.to_dict()))
    loaded = Scene.load(path)
    assert loaded == scene
    assert loaded.design == (70e-6, 130e-6)


def test_toml_round_trip(tmp_path):
    scene = default_scene(t_oca1=55e-6, t_oca2=145e-6, output_dt=2e-6, half_width=6e-3)
    path = tmp_path / "scene.toml"
    path.write_text(_to_toml(scene.to_dict()))
    loaded = Scene.load(path)
    assert loaded == scene
    assert hash(loaded) == hash(scene)  # frozen, tuples only


def test_handwritten_toml_partial_uses_defaults(tmp_path):
    path = tmp_path / "panel.toml"
    path.write_text(
        'analysis = "plane_strain"\n'
        'design_layers = ["A"]\n'
        'contact_pairs = [["ball", "TOP"]]\n'
        "[ball]\nvelocity = 1.5\n"
        '[[layers]]\nname = "TOP"\nyoungs = 70e9\npoisson = 0.22\nthickness = 200e-6\ndensity = 2500.0\n'
        '[[layers]]\nname = "A"\nyoungs = 1e7\npoisson = 0.45\nthickness = 80e-6\ndensity = 1050\n')
    s = Scene.load(path)
    assert s.analysis == "plane_strain"
    assert s.ball.velocity == 1.5 and s.ball.radius == Ball().radius
    assert s.part_names == ("ball", "TOP", "A")
    assert s.design == (80e-6,)
    assert s.n_frames == Scene().n_frames


def test_to_dict_is_plain_and_not_aliased():
    scene = default_scene()
    d = scene.to_dict()
    json.dumps(d)  # JSON-serialisable
    d2 = copy.deepcopy(d)
    d["layers"][0]["thickness"] = 1.0
    assert Scene.from_dict(d2) == scene


# ---- designs ------------------------------------------------------------------------------------
def test_with_design():
    scene = default_scene()
    new = scene.with_design(60e-6, 140e-6)
    assert new.design == (60e-6, 140e-6)
    assert scene.design == (100e-6, 100e-6)  # original untouched (frozen)
    by_name = {layer.name: layer for layer in new.layers}
    assert by_name["OCA1"].thickness == 60e-6 and by_name["OCA2"].thickness == 140e-6
    for old, nl in zip(scene.layers, new.layers):
        if old.name not in ("OCA1", "OCA2"):
            assert old == nl
    assert new.panel_thickness == pytest.approx(scene.panel_thickness)
    assert new == default_scene(t_oca1=60e-6, t_oca2=140e-6)
    with pytest.raises(ValueError, match="design"):
        scene.with_design(60e-6)
    with pytest.raises(ValueError, match=r"thickness.*-6e-05"):
        scene.with_design(-60e-6, 100e-6)


def test_paper_defaults():
    s = default_scene()
    assert s.part_names == ("ball", "CG", "OCA1", "POL", "OCA2", "OLED", "PLATE")
    assert s.analysis == "axisymmetric"
    assert s.ball.mass_full == pytest.approx(4.110e-3, rel=1e-3)
    assert [layer.name for layer in paper_layers()] == list(s.part_names[1:])
