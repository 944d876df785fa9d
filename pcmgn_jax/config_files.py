"""The older forms of a run's config.json, read by :meth:`pcmgn_jax.config.TrainConfig.from_json`: the flat
files (the formulation a name, its fields beside it under their old names), the fields whose defaults moved, and
the research toggles that were removed (loaded when off, refused by name when on); and the scene features' comma
list (:func:`scene_feature_names`), which old files and the command line write."""
from __future__ import annotations

# the defaults these fields had before TrainConfig() became the main job's (cpu preset's) configuration: a
# config.json written before a field existed (to_dict writes every field) ran with them, so a missing key means them
BEFORE_MAIN_JOB_DEFAULTS = {"ema_decay": 0.0, "lambda_start": 0.0, "epochs": 20, "num_steps": 0, "val_every": 1000}


# research toggles that lost when measured and are in no paper study: removed from the config. An older
# config.json that holds one at its off value still loads; one that switched it on is refused, naming the page
# that keeps the toggle's measured result.
RETIRED_FIELDS = {
    "pushforward": (False, "docs/results/changelog.md (pushforward training: 8.7 µm position MAE against 4.7 µm "
                           "without, the dynamic panel)"),
}


def drop_retired(data: dict) -> dict:
    """``data`` without the :data:`RETIRED_FIELDS` keys; ``ValueError`` naming a key set to anything but its
    off value."""
    for key, (off, where) in RETIRED_FIELDS.items():
        if key in data and data.pop(key) != off:
            raise ValueError(f"config: {key} was removed (a research toggle that lost when measured, in no paper "
                             f"study; its result: {where}); this config switched it on, so this code cannot "
                             f"load or resume it: use the commit that trained it")
    return data


def from_flat(data: dict) -> dict:
    """An older flat config.json's keys (``formulation`` a name; ``target``, ``ball_model``, ``"on"/"off"``
    ``contact_projection``, comma-list ``scene_features``, ``""`` = the formulation's) as overrides for
    :func:`resolve_formulation`."""
    data = dict(data)
    kw = {k: data.pop(k) for k in ("ball_target", "panel_target", "normalization", "features",
                                   "loss_weighting", "panel_model") if k in data}
    kw = {k: v for k, v in kw.items() if v}  # "" = the formulation's
    target = data.pop("target", "")
    if target:
        kw.setdefault("ball_target", target)
        kw.setdefault("panel_target", target)
    ball_model = data.pop("ball_model", "")
    if ball_model:
        if ball_model not in ("rigid", "nodes"):
            raise ValueError(f"config: ball_model={ball_model!r} must be rigid or nodes")
        kw["rigid_ball"] = ball_model == "rigid"
    projection = data.pop("contact_projection", "")
    if projection:
        if projection not in ("on", "off"):
            raise ValueError(f"config: contact_projection={projection!r} must be on or off")
        kw["contact_projection"] = projection == "on"
    scene = data.pop("scene_features", "")
    if scene:
        kw["scene_features"] = scene_feature_names(scene)
    kw.setdefault("processor", "per_frame")  # flat configs predate the per-design processor
    return {**data, "formulation": data.get("formulation") or "default", **kw}


def scene_feature_names(value) -> tuple[str, ...]:
    """Scene feature names as a tuple, from a tuple/list or a comma list (``"ball_radius,layer_thickness"``;
    ``"none"`` or ``""``: no features)."""
    items = value.split(",") if isinstance(value, str) else value
    return tuple(f.strip() for f in items if f.strip() and f.strip() != "none")
