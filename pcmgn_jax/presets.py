"""The presets, one entry each: training settings, mesh resolution and scene family in one place.

    PRESETS["cpu"].train      # TrainConfig fields (pcmgn_jax.config.TrainConfig.from_preset)
    PRESETS["cpu"].mesh       # MeshSpec fields, lengths [m] (pcmgn_jax.sim.mesh.MESH_PRESETS)
    PRESETS["family"].family  # the scene family ("" none | scene | stack; pcmgn_jax.data.designs.FAMILIES)

A preset's name is also its dataset's (``data_preset``, ``data/<name>``); the views the layers use are built from
this table: the training defaults (:meth:`pcmgn_jax.config.TrainConfig.from_preset`), the meshes
(:data:`pcmgn_jax.sim.mesh.MESH_PRESETS`) and the scene families (:data:`pcmgn_jax.data.designs.FAMILIES`). Plain
data: this module imports nothing of the package, so every layer may read it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Mapping, get_args

PresetName = Literal["tiny", "cpu", "paper", "family", "family_tiny", "stack", "stack_tiny"]
PRESET_NAMES: tuple[str, ...] = get_args(PresetName)
FamilyKind = Literal["", "scene", "stack"]


@dataclass(frozen=True)
class Preset:
    """One preset (module docstring). ``family``: "" the paper's scene, whose designs are its design layers'
    thicknesses; ``scene`` a :class:`pcmgn_jax.data.designs.SceneFamily` (ball radius and speed, OCA1, OCA2 and POL
    thicknesses vary); ``stack`` a :class:`pcmgn_jax.data.stack.StackFamily` (stacks of 5-7 layers)."""

    train: Mapping[str, Any]   # TrainConfig fields (formulation fields by name), over TrainConfig's defaults
    mesh: Mapping[str, Any]    # pcmgn_jax.sim.mesh.MeshSpec fields [m], over MeshSpec's defaults
    family: FamilyKind = ""    # the scene family: "" | scene | stack (above)
    n_frames: int = 0          # a family's window: frames of the base scene's output_dt (0: the scene's own)


# the stack presets' inputs
STACK_FEATURES = ("ball_radius", "material", "own_thickness", "layer_depth", "total_thickness")

# meshes: 'tiny' a few hundred nodes for tests; 'cpu' the 2-core default (~25 um at the contact); 'paper' the paper's
# resolution (<= 10 um at the contact; ~7.7k solver nodes, ~3.2k graph nodes in the region of interest, like the
# paper's 11.5-14.4k -> 2.4-3.1k), for a GPU. The families' meshes (thickness_elems): OCA1, POL, OCA2 and any
# other layer but CG, OLED and the plate get ceil(t / h_layer) elements, so meshes differ between scenes;
# 'family' between tiny and cpu (35 um at the contact) with the objective's 3 mm section in the ROI
_TINY_MESH = dict(h_contact=50e-6, fine_radius=0.4e-3, fine_depth=0.1e-3, growth=1.4,
                  layer_elems={"CG": 2, "OCA1": 2, "POL": 1, "OCA2": 2, "OLED": 1, "PLATE": 3},
                  h_layer=50e-6, bottom_growth=1.6, roi_x=1.0e-3, roi_ball_height=0.5e-3)
_FAMILY_MESH = dict(h_contact=35e-6, fine_radius=0.45e-3, fine_depth=0.1e-3, growth=1.3,
                    layer_elems={"CG": 3, "OLED": 1, "PLATE": 5}, h_layer=35e-6, bottom_growth=1.5,
                    roi_x=3.0e-3, roi_ball_height=0.5e-3, thickness_elems=True)
_FAMILY_TINY_MESH = dict(h_contact=50e-6, fine_radius=0.4e-3, fine_depth=0.1e-3, growth=1.4,
                         layer_elems={"CG": 2, "OLED": 1, "PLATE": 3}, h_layer=50e-6, bottom_growth=1.6,
                         roi_x=1.0e-3, roi_ball_height=0.5e-3, thickness_elems=True)
# training: TrainConfig() is the cpu preset's (the main job's) model, loss, optimiser and bookkeeping; a preset's
# `train` holds only what differs from it. The small and paper presets keep no parameter average, the penalty from
# step 0 and the epoch count they were measured with:
_NO_MAIN_JOB = dict(ema_decay=0.0, lambda_start=0.0, epochs=20, num_steps=0, val_every=1000)

PRESETS: dict[str, Preset] = {
    # tests and smoke checks: tiny mesh, small model, < 1 min
    "tiny": Preset(
        train=dict(_NO_MAIN_JOB, n_train=3, n_val=1, n_test=2, latent_size=32, message_passing_steps=3, epochs=1,
                   num_steps=400, steps_per_dispatch=20, log_every=20, ckpt_every=200, val_every=200),
        mesh=_TINY_MESH),
    # the README's main job on a 2-core CPU: the project's default formulation (rigid ball, quasi-static
    # panel, per-part normalisation, strain features, contact projection); the parameters' moving
    # average is validated and kept (validation MAE swings between checkpoints otherwise); no noise (nothing of
    # the panel's state is an input, so there is no rollout error to imitate); no penetration term: lambda = 10
    # from step 0 or from half-way harmful to this formulation (docs/results/surrogate.md,
    # results/ablation/panel.md); with --lambda_pen > 0 the term starts half-way (lambda_start)
    "cpu": Preset(
        train=dict(),
        mesh=dict(h_contact=25e-6, fine_radius=0.5e-3, fine_depth=0.1e-3, growth=1.2,
                  layer_elems={"CG": 4, "OCA1": 3, "POL": 2, "OCA2": 3, "OLED": 2, "PLATE": 6},
                  h_layer=25e-6, bottom_growth=1.4, roi_x=3.0e-3, roi_ball_height=0.6e-3)),
    # the paper: 15 x 128, 100 epochs, 100 training / 50 test trajectories (a GPU job); the paper's best:
    # B.6/P.5, lambda = 10
    "paper": Preset(
        train=dict(_NO_MAIN_JOB, n_train=100, n_val=5, n_test=50, latent_size=128, message_passing_steps=15,
                   epochs=100, steps_per_dispatch=50, log_every=500, ckpt_every=10000, val_every=10000,
                   formulation="paper", lambda_pen=10.0, noise_std=3e-7, noise_parts="all"),
        mesh=dict(fine_radius=0.4e-3, fine_depth=0.08e-3, growth=1.2,
                  layer_elems={"CG": 10, "OCA1": 5, "POL": 4, "OCA2": 5, "OLED": 3, "PLATE": 8},
                  roi_x=3.0e-3, roi_ball_height=0.5e-3)),
    # scene family: ball radius, drop speed, OCA1/OCA2/POL thicknesses vary, every scene on its own
    # mesh; the cpu preset's model and loss (no penetration term: the default formulation's contact projection
    # stands in for it), 2 graphs per step, the ball radius as a node input (the speed is in the velocity
    # state), heights from the plate's top: a plate change moves nothing above it (design §5)
    "family": Preset(
        train=dict(n_train=22, n_val=2, n_test=8, batch_graphs=2,
                   scene_features=("ball_radius", "layer_thickness"), origin="support_top"),
        mesh=_FAMILY_MESH, family="scene", n_frames=100),
    # tests and smoke checks of the family path: a handful of tiny scenes (80 us), a small model, seconds
    "family_tiny": Preset(
        train=dict(_NO_MAIN_JOB, n_train=4, n_val=1, n_test=2, latent_size=32, message_passing_steps=3, epochs=1,
                   num_steps=60, steps_per_dispatch=20, batch_graphs=2, log_every=20, ckpt_every=60, val_every=60,
                   formulation="default", lambda_pen=10.0, noise_rel=1.0, noise_parts="panel",
                   scene_features=("ball_radius", "layer_thickness"), origin="support_top"),
        mesh=_FAMILY_TINY_MESH, family="scene", n_frames=20),
    # panel stacks of 5-7 layers: inputs that do not depend on a layer's index (docs/design.md §5):
    # six role node types (ball, contact layer, film, OLED, support, fixed) whatever the layer count, each
    # node's own material, layer thickness and depth below the contact layer's top, the stack's total
    # thickness, heights from the contact layer's top; the family preset's mesh, model and loss
    "stack": Preset(
        train=dict(n_train=100, n_val=4, n_test=20, batch_graphs=2, scene_features=STACK_FEATURES,
                   part_identity="role", origin="contact_top"),
        mesh=_FAMILY_MESH, family="stack", n_frames=100),
    # tests and smoke checks of the stack path: tiny stacks, a small model, seconds
    "stack_tiny": Preset(
        train=dict(_NO_MAIN_JOB, n_train=4, n_val=1, n_test=2, latent_size=32, message_passing_steps=3, epochs=1,
                   num_steps=40, steps_per_dispatch=20, batch_graphs=2, log_every=20, ckpt_every=40, val_every=40,
                   formulation="default", lambda_pen=0.0, noise_std=0.0, noise_rel=0.0, noise_parts="none",
                   scene_features=STACK_FEATURES, part_identity="role", origin="contact_top"),
        mesh=_FAMILY_TINY_MESH, family="stack", n_frames=20),
}
assert tuple(PRESETS) == PRESET_NAMES, "PresetName must list the presets in PRESETS' order"
