"""One home per preset (pcmgn_jax/presets.py): the training defaults, the meshes and the scene families are views
of that one table, and the options a user sees are typed with ``Literal`` (the command line lists and checks them)."""
from __future__ import annotations

import typing

import pytest

from pcmgn_jax import cli
from pcmgn_jax.config import FORMULATION_FIELDS, RESIDUAL_BALLS, RESIDUAL_BASES, DataConfig, LossConfig, TrainConfig
from pcmgn_jax.data.designs import FAMILIES, SceneFamily
from pcmgn_jax.data.stack import STACK_FAMILIES, StackFamily
from pcmgn_jax.mgn import formulation as fm
from pcmgn_jax.presets import PRESET_NAMES, PRESETS, PresetName
from pcmgn_jax.sim.mesh import MESH_PRESETS, MeshSpec


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_every_view_of_a_preset_comes_from_its_one_entry(name):
    p = PRESETS[name]
    cfg = TrainConfig.from_preset(name)
    assert cfg.preset == cfg.data_preset == name
    for key, value in p.train.items():
        if key == "formulation":                  # a preset names its base formulation
            key = "formulation_name"
        assert getattr(cfg.formulation if key in FORMULATION_FIELDS else cfg, key) == value, key
    assert MESH_PRESETS[name] == MeshSpec(**p.mesh)
    family = FAMILIES.get(name)
    if p.family == "":
        assert family is None and p.n_frames == 0
    else:
        assert isinstance(family, {"scene": SceneFamily, "stack": StackFamily}[p.family])
        assert family.n_frames == p.n_frames > 0
        assert (name in STACK_FAMILIES) == (p.family == "stack")


def test_the_preset_names_are_one_literal_type():
    assert tuple(PRESETS) == PRESET_NAMES == typing.get_args(PresetName)
    assert typing.get_type_hints(DataConfig)["preset"] == PresetName
    with pytest.raises(ValueError, match="unknown preset 'huge'"):
        cli.parse_config(["--preset", "huge"])


def test_string_options_are_literal_types_with_their_allowed_values():
    """Each option with a tuple of allowed values is typed with the Literal of the same values (the one the
    tuple is made from), so tyro's --help lists them and the command line refuses anything else."""
    hints = typing.get_type_hints(fm.Formulation)
    for field, allowed in (("ball_target", fm.TARGETS), ("panel_target", fm.TARGETS),
                           ("normalization", fm.NORMALIZATIONS), ("features", fm.FEATURES),
                           ("loss_weighting", fm.LOSS_WEIGHTINGS), ("panel_model", fm.PANEL_MODELS),
                           ("processor", fm.PROCESSORS), ("part_identity", fm.PART_IDENTITIES),
                           ("origin", fm.ORIGINS), ("reach", fm.REACHES), ("stress_target", fm.STRESS_TARGETS)):
        assert typing.get_args(hints[field]) == allowed, field
    hints = typing.get_type_hints(LossConfig)
    for field, allowed in (("noise_parts", fm.NOISE_PARTS), ("residual_of", RESIDUAL_BASES),
                           ("residual_ball", RESIDUAL_BALLS)):
        assert typing.get_args(hints[field]) == allowed, field
    with pytest.raises((ValueError, SystemExit)):
        cli.parse_config(["--preset", "tiny", "--panel_target", "sideways"])
    assert cli.parse_config(["--preset", "tiny", "--reach", "attention"]).formulation.reach == "attention"
