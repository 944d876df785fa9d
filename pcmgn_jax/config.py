"""Training configuration: frozen dataclasses nested by concern (data, model, loss, optim, log), one home per default.

``TrainConfig()`` is the main job's (the ``cpu`` preset's) configuration; a preset's values over it live in
:data:`pcmgn_jax.presets.PRESETS` (its ``train`` settings). Fields go by their flat names everywhere (``cfg.n_train``,
``cfg.replace(latent_size=32)``, ``--n_train`` on the command line: :func:`pcmgn_jax.cli.parse_train`; the library
takes configs, never flags). The formulation (:class:`pcmgn_jax.mgn.formulation.Formulation`) nests in ``model``; a
preset names its base (``formulation="default"``) and may override its fields. Unknown keys raise ``ValueError``;
:meth:`TrainConfig.from_json` also reads the older forms of config.json (no groups; flat, the formulation a name).

    cfg = TrainConfig.from_preset("tiny", lambda_pen=0.0, latent_size=32)
    cfg.save_json(workdir / "config.json")
"""
from __future__ import annotations

import dataclasses
import json
import math
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, get_args

from pcmgn_jax.config_files import BEFORE_MAIN_JOB_DEFAULTS, drop_retired, from_flat, scene_feature_names
from pcmgn_jax.mgn.formulation import FORMULATIONS, NOISE_PARTS, Formulation, NoiseParts
from pcmgn_jax.presets import PRESETS, PresetName
from pcmgn_jax.surrogates.kinds import names as kind_names

# residual_of: "" or a baseline the network can learn a correction of (the registry's kinds with residual_base)
ResidualBase = Literal[("",) + kind_names(residual_base=True)]
ResidualBall = Literal["baseline", "network"]  # residual_ball: who moves the rigid ball in a residual run's rollout
RESIDUAL_BASES, RESIDUAL_BALLS = get_args(ResidualBase), get_args(ResidualBall)
SelectOn = Literal["position", "objective"]     # select_on: the validation figure the best checkpoint is chosen on
SELECT_ON = get_args(SelectOn)


@dataclass(frozen=True)
class DataConfig:
    """``TrainConfig.data``: the data: which dataset, which trajectories."""
    preset: PresetName = "cpu"       # which preset filled the defaults (pcmgn_jax.presets.PRESETS)
    data_preset: PresetName = "cpu"  # mesh/solver preset handed to dataset.ensure_dataset (a preset's own name)
    dataset_dir: str = ""            # dataset root; "" -> data/<data_preset>
    # training trajectories, validation excluded (the train split holds n_train + n_val); with --dataset_dir of a
    # generated dataset: its manifest's unless given
    n_train: int = 12
    n_val: int = 2                   # held out from the train split for the validation rollout (after the n_train)
    # test trajectories (evaluation); with --dataset_dir of a generated dataset: its manifest's test count unless given
    n_test: int = 6
    data_seed: int = 0               # seed of the Latin-hypercube designs for dataset generation


@dataclass(frozen=True)
class ModelConfig:
    """``TrainConfig.model``: the model: graph, network size and the formulation (what it predicts)."""
    contact_radius: float = 0.0      # r_w [m]; 0 -> auto: 1.5 x median CG top-surface side length
    contact_capacity_factor: float = 2.0  # contact buffer = factor x max pairs seen in training
    latent_size: int = 64            # width of every MLP layer and of the latents
    mlp_layers: int = 2              # hidden layers per MLP
    message_passing_steps: int = 8   # processor blocks (paper: 2 x 128, 15 steps)
    # formulation: what the model predicts (pcmgn_jax/mgn/formulation.py; docs/design.md §5); its fields are flags
    # of their own (--ball_target, --panel_target, --rigid_ball, --normalization,
    # --features, --loss_weighting, --scene_features, --panel_model, --contact_projection, --processor);
    # --formulation=paper|default|dynamic|realtime selects the base
    formulation: Formulation = FORMULATIONS["default"]
    # the FORMULATIONS entry the formulation started from (paper | default | dynamic); a record: `formulation` is the
    # truth
    formulation_name: str = "default"


@dataclass(frozen=True)
class LossConfig:
    """``TrainConfig.loss``: the loss: its terms, the residual mode, the input noise, frames per sample."""
    lambda_pen: float = 0.0          # weight of the penetration term (0 = vanilla MGN; paper: 10)
    # weight of the objective term: per graph, the squared error of the OLED's objective-section mean von
    # Mises (normalised; docs/design.md §7); 0 = off
    lambda_obj: float = 0.0
    # the OLED's share of the stress term: its nodes' stress weights x this factor, every graph's weights then
    # rescaled to sum 1 (pcmgn_jax.train.setup.emphasise_part); 1 = off. A target chosen from the error budget
    # (docs/results/compute.md): the objective's error is the OLED stress map's own, not drift
    oled_stress_weight: float = 1.0
    # "" (the network predicts the fields) | rom: the network predicts what the named baseline gets wrong (the panel's
    # displacement and every node's von Mises minus the baseline's, out-of-fold on the training scenes); a rollout adds
    # the baseline back (pcmgn_jax/surrogates/residual.py; docs/design.md §5.2)
    residual_of: ResidualBase = ""
    # with residual_of, where a rollout's rigid ball goes: baseline (the baseline's ball trajectory; the network
    # corrects the panel's fields along it) | network (the network's own ball dynamics);
    # rollout-only (evaluate --residual_ball overrides)
    residual_ball: ResidualBall = "baseline"
    # fraction of training before the penetration term switches on (then a 10 % linear ramp; 0 = from step 0, the
    # paper); the main job's 0.5: with --lambda_pen > 0 the term starts half-way
    lambda_start: float = 0.5
    poly_ball: int = 6               # polynomial degree of the ball boundary fit (penetration term)
    poly_panel: int = 5              # polynomial degree of the cover-glass fit (penetration term)
    pen_x_max: float = 1e-3          # [m] boundary nodes with reference x <= this enter the fits
    pen_length_scale: float = 1e-6   # [m] unit of the penetration depth d in L_pen (µm, see penetration.py)
    noise_std: float = 0.0           # Gaussian noise on the input displacement [m], all noised nodes (paper: 3e-7)
    noise_rel: float = 0.0           # used when noise_std = 0: sigma per part = noise_rel x its RMS motion per frame
    noise_parts: NoiseParts = "none"  # none | ball | panel | all
    # frames of each sample's trajectory decoded from its one processor pass per step (the sample's and F-1 more, evenly
    # spread); > 1 needs processor='per_design'; 0 = auto: 8 with processor='per_design', else 1
    frames_per_sample: int = 0


@dataclass(frozen=True)
class OptimConfig:
    """``TrainConfig.optim``: the optimiser: seed, learning rate and decay, parameter average, steps, batches."""
    seed: int = 0                    # model init, data order and noise
    learning_rate: float = 1e-3      # Adam initial learning rate (paper)
    # >0: validate and keep as "best" the exponential moving average of the parameters (Polyak); 0 = off. The main
    # job's 0.998: its validation MAE swings between checkpoints otherwise
    ema_decay: float = 0.998
    lr_decay_rate: float = 0.1       # exponential decay: lr = lr0 * rate ** (step / lr_decay_steps)
    lr_decay_steps: int = 0          # 0 -> total number of steps (lr ends at lr0 * rate)
    epochs: int = 1                  # passes over all (trajectory, frame) pairs (used when num_steps = 0)
    num_steps: int = 4000            # >0 overrides epochs: total optimiser steps
    # graphs per step over all devices (any meshes: one padded disjoint union per device); paper: 1
    batch_graphs: int = 1
    steps_per_dispatch: int = 25     # optimiser steps per jitted call (lax.scan)
    devices: int = 1                 # data-parallel devices splitting each batch (0 = all); divides batch_graphs


@dataclass(frozen=True)
class LogConfig:
    """``TrainConfig.log``: bookkeeping: logs, checkpoints, validation, progress bar."""
    log_every: int = 100             # steps between metrics.jsonl lines (rounded to the dispatch)
    ckpt_every: int = 1000           # steps between periodic checkpoints (rounded to the dispatch)
    val_every: int = 500             # steps between validation rollouts (best checkpoint)
    # what the best checkpoint is chosen on: position (the validation rollouts' position MAE) | objective (their
    # area-mean OLED objective's mean relative error, the evaluation's figure; needs an 'OLED' part)
    select_on: SelectOn = "position"
    max_to_keep: int = 2             # periodic checkpoints kept
    progress: bool = True            # tqdm progress bar


@dataclass(frozen=True)
class TrainConfig:
    """The training configuration, nested by concern; ``TrainConfig()`` is the main job's (the ``cpu`` preset's).

    Each field has one home, its group; ``cfg.n_train`` reads ``cfg.data.n_train`` (every field name is unique
    over the groups), and :meth:`of`, :meth:`replace` and :meth:`from_preset` take fields by their flat names.
    The command line's flags are the flat names too (``--n_train``; tyro's ``OmitArgPrefixes``)."""

    data: DataConfig = DataConfig()
    model: ModelConfig = ModelConfig()
    loss: LossConfig = LossConfig()
    optim: OptimConfig = OptimConfig()
    log: LogConfig = LogConfig()

    def __getattr__(self, name: str):   # only called for names that are not the groups
        group = GROUP_OF.get(name)
        if group is None:
            raise AttributeError(f"TrainConfig has no field {name!r}")
        return getattr(object.__getattribute__(self, group), name)

    @classmethod
    def of(cls, **fields: Any) -> "TrainConfig":
        """The config of ``TrainConfig()`` with ``fields`` (flat names) set; ``ValueError`` naming unknown ones."""
        return cls().replace(**fields)

    def __post_init__(self):
        def bad(name, why):
            raise ValueError(f"config: {name}={getattr(self, name)!r} {why}")
        if self.preset not in PRESETS:
            bad("preset", f"must be one of {sorted(PRESETS)}")
        if self.formulation_name not in FORMULATIONS:
            bad("formulation_name", f"must be one of {sorted(FORMULATIONS)}")
        if not isinstance(self.formulation, Formulation):
            bad("formulation", "must be a pcmgn_jax.mgn.formulation.Formulation")
        if self.select_on not in SELECT_ON:
            bad("select_on", f"must be one of {SELECT_ON}")
        if self.noise_parts not in NOISE_PARTS:
            bad("noise_parts", f"must be one of {NOISE_PARTS}")
        for name in ("n_train", "latent_size", "mlp_layers", "batch_graphs", "steps_per_dispatch",
                     "log_every", "ckpt_every", "val_every", "max_to_keep", "epochs"):
            if getattr(self, name) < 1:
                bad(name, "must be >= 1")
        for name in ("n_val", "n_test", "message_passing_steps", "num_steps", "lr_decay_steps", "devices"):
            if getattr(self, name) < 0:
                bad(name, "must be >= 0")
        if not 0 <= self.ema_decay < 1:
            bad("ema_decay", "must be in [0, 1) (0 = no parameter average)")
        if not 0 <= self.lambda_start < 1:
            bad("lambda_start", "must be in [0, 1) (a fraction of the training steps)")
        for name in ("contact_radius", "contact_capacity_factor", "noise_std", "noise_rel", "lambda_pen", "lambda_obj",
                     "oled_stress_weight", "pen_x_max", "pen_length_scale", "lr_decay_rate"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                bad(name, "must be a finite number >= 0")
        if self.formulation.reach == "attention" and self.latent_size % self.formulation.reach_heads:
            bad("latent_size", f"must be divisible by reach_heads={self.formulation.reach_heads} (reach='attention' "
                "splits the latent over its heads)")
        if self.residual_of not in RESIDUAL_BASES:
            bad("residual_of", f"must be one of {RESIDUAL_BASES} ('' = the network predicts the fields themselves)")
        if self.residual_of and (self.formulation.panel_model != "quasi_static" or self.lambda_pen > 0):
            bad("residual_of", "needs formulation panel_model='quasi_static' and lambda_pen=0: only a panel whose "
                "fields are outputs, never inputs, can be predicted as a baseline's residual, and the penetration "
                f"term would judge the residual as a position (got panel_model={self.formulation.panel_model!r}, "
                f"lambda_pen={self.lambda_pen:g})")
        if self.residual_of and self.formulation.stress_target != "linear":
            bad("residual_of", "needs formulation stress_target='linear': a residual stress is signed, and the log "
                f"target is of a stress >= 0 (got stress_target={self.formulation.stress_target!r})")
        if self.residual_ball not in RESIDUAL_BALLS:
            bad("residual_ball", f"must be one of {RESIDUAL_BALLS}")
        if not 0 < self.learning_rate < 1:
            bad("learning_rate", "must be in (0, 1)")
        if self.frames_per_sample < 0:
            bad("frames_per_sample", "must be >= 0 (0 = auto)")
        if self.frames_per_sample > 1 and self.formulation.processor != "per_design":
            bad("frames_per_sample", "> 1 needs formulation processor='per_design' (one processor pass shared by the "
                "frames of a design)")
        if self.devices:  # 0 (all devices) is checked once jax knows how many (train.sharding)
            check_batch_split(self.batch_graphs, self.devices)

    # ---- construction ------------------------------------------------------------------------
    @classmethod
    def from_preset(cls, preset: str = "cpu", **overrides: Any) -> "TrainConfig":
        if preset not in PRESETS:
            raise ValueError(f"config: unknown preset {preset!r}; choose one of {sorted(PRESETS)}")
        return cls.of(**resolve_formulation(preset_settings(preset), overrides))

    @classmethod
    def from_json(cls, data: dict) -> "TrainConfig":
        """A config from its ``to_dict()`` form (``formulation`` nested), from the groups' form (``asdict``:
        ``{"data": {...}, "model": {...}, ...}``), or from an older flat config.json (``formulation`` a name,
        its fields beside it under their old names: converted)."""
        data = dict(data)
        for group in GROUPS:
            if isinstance(data.get(group), dict):
                inner = data.pop(group)
                _check_keys(inner, GROUP_TYPES[group], f"config {group}")
                data.update(inner)
        data = {**BEFORE_MAIN_JOB_DEFAULTS, **drop_retired(data)}
        if isinstance(data.get("formulation"), dict):
            form = dict(data.pop("formulation"))
            if "scene_features" in form:
                form["scene_features"] = tuple(form["scene_features"])
            _check_keys(form, Formulation, "config formulation")
            data["formulation"] = Formulation(**form)
            _check_keys(data, FIELDS, "config")
            return cls.of(**data)
        return cls.of(**resolve_formulation({}, from_flat(data)))

    @classmethod
    def load(cls, path: str | Path) -> "TrainConfig":
        """The config saved in ``path`` (a run's config.json); ValueError naming the file when it is missing,
        empty or not JSON."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            raise ValueError(f"{path}: no such config file") from None
        except (OSError, ValueError) as err:    # json.JSONDecodeError, UnicodeDecodeError are ValueErrors
            raise ValueError(f"{path}: not a run config (empty, or not JSON: {err})") from None
        return cls.from_json(data)

    def to_dict(self) -> dict:
        """{field: value} by the fields' flat names (the formulation a nested dict): config.json's form, which
        the groups leave as it was, so a run's config.json reads the same to every tool."""
        return {k: v for group in dataclasses.asdict(self).values() for k, v in group.items()}

    def save_json(self, path: str | Path) -> None:
        from pcmgn_jax.atomic import atomic_write_text
        atomic_write_text(path, json.dumps(self.to_dict(), indent=2, sort_keys=True) + "\n")

    def replace(self, **kw) -> "TrainConfig":
        """This config with fields replaced, by their flat names (``latent_size=32``) or whole groups."""
        groups = {g: kw.pop(g) for g in GROUPS if g in kw}
        _check_keys(kw, FIELDS, "config")
        for g in GROUPS:
            mine = {k: v for k, v in kw.items() if GROUP_OF[k] == g}
            if mine:
                groups[g] = dataclasses.replace(groups.get(g, getattr(self, g)), **mine)
        return dataclasses.replace(self, **groups)

    @property
    def scan_formulation(self) -> Formulation:
        """The formulation a rollout's ``lax.scan`` runs (:func:`pcmgn_jax.mgn.checkpoint.make_spec`): the
        run's, except that with ``residual_of`` the contact projection leaves the scan (the network's panel
        output is then a residual, not a position); it acts on the corrected field once the baseline is
        added (:meth:`pcmgn_jax.surrogates.mgn.MGNSurrogate.rollout_trajectories`,
        :func:`pcmgn_jax.surrogates.correction.rigid_contact`)."""
        if self.residual_of:
            return self.formulation.replace(contact_projection=False)
        return self.formulation

    @property
    def frames(self) -> int:
        """Frames per training sample: ``frames_per_sample``, or with 0 (auto) 8 for a per-design
        processor (its decoder is ~1/25 of a processor pass: 8 readouts cost ~1.3 passes) and 1 otherwise."""
        if self.frames_per_sample:
            return self.frames_per_sample
        return 8 if self.formulation.processor == "per_design" else 1

    @property
    def resolved_dataset_dir(self) -> str:
        return self.dataset_dir or f"data/{self.data_preset}"


def config_diff(old, new, prefix: str = "") -> dict[str, tuple[Any, Any]]:
    """Fields whose values differ: {name: (old value, new value)}, in field order; fields of a nested
    dataclass are named with its field's prefix (``formulation.panel_target``), except a TrainConfig group's,
    which keep their flat names (``n_train``, the flag's)."""
    out: dict[str, tuple[Any, Any]] = {}
    for f in dataclasses.fields(old):
        a, b = getattr(old, f.name), getattr(new, f.name)
        if dataclasses.is_dataclass(a) and type(a) is type(b):
            group = isinstance(old, TrainConfig) and f.name in GROUPS
            out.update(config_diff(a, b, prefix=prefix if group else f"{prefix}{f.name}."))
        elif a != b:
            out[prefix + f.name] = (a, b)
    return out


def check_resume(cfg: TrainConfig, workdir: str | Path) -> None:
    """Raise ``ValueError`` naming every field where ``cfg`` differs from ``workdir/config.json``."""
    path = Path(workdir) / "config.json"
    if not path.exists():
        return
    diff = config_diff(TrainConfig.load(path), cfg)
    if diff:
        lines = ", ".join(f"{k}: saved {a!r}, given {b!r}" for k, a, b in ((k, *v) for k, v in diff.items()))
        raise ValueError(f"the config differs from the run's {path} in {sorted(diff)} ({lines}); a resumed run "
                         f"keeps its saved config: resume with the saved values, or train in a new folder")


FORMULATION_FIELDS = tuple(f.name for f in dataclasses.fields(Formulation))
GROUP_TYPES = typing.get_type_hints(TrainConfig)                                         # {group: its dataclass}
GROUPS = tuple(GROUP_TYPES)
GROUP_OF = {f.name: g for g, t in GROUP_TYPES.items() for f in dataclasses.fields(t)}   # {field: its group}
FIELDS = tuple(GROUP_OF)                                                                  # every field's flat name
def _check_keys(data: dict, cls, where: str) -> None:
    """``ValueError`` naming the keys of ``data`` that are not fields of dataclass ``cls`` (or not in a tuple)."""
    names = set(cls) if isinstance(cls, tuple) else {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}")


def resolve_formulation(base: dict, overrides: dict, *, check: bool = True) -> dict:
    """TrainConfig keyword arguments from ``base`` (a preset) and ``overrides``, where either may name the
    formulation (``formulation="paper"``: sets ``formulation_name`` and the base :class:`Formulation`) and
    give :class:`Formulation` fields by name (``panel_target="velocity"``, applied on top, the preset's first).
    A :class:`Formulation` object as ``overrides["formulation"]`` is taken as it is (then only the overrides'
    fields apply). Raises ``ValueError`` naming unknown keys (``check=False``: a partial set of keys)."""
    kw = {**base, **overrides}
    fields = {k: kw.pop(k) for k in FORMULATION_FIELDS if k in kw}
    form = kw.pop("formulation", None)
    if isinstance(form, Formulation):
        fields = {k: v for k, v in fields.items() if k in overrides}
    else:
        name = form or kw.get("formulation_name", "default")
        if name not in FORMULATIONS:
            raise ValueError(f"config: formulation={name!r} must be one of {sorted(FORMULATIONS)}")
        form, kw["formulation_name"] = FORMULATIONS[name], name
    if "scene_features" in fields:
        fields["scene_features"] = scene_feature_names(fields["scene_features"])
    if check:
        _check_keys(kw, FIELDS, "config")
    return {**kw, "formulation": form.replace(**fields)}


def check_batch_split(batch_graphs: int, devices: int) -> None:
    """Data parallelism splits every batch evenly: ``ValueError`` unless ``devices`` divides ``batch_graphs``."""
    if batch_graphs % devices:
        raise ValueError(f"config: batch_graphs={batch_graphs} is not divisible by devices={devices}; each "
                         f"device takes batch_graphs / devices graphs of every step (e.g. batch_graphs="
                         f"{devices * max(1, round(batch_graphs / devices))})")


def preset_settings(preset: str) -> dict[str, Any]:
    """TrainConfig keyword arguments of ``preset`` (:data:`pcmgn_jax.presets.PRESETS`): its ``train`` settings,
    its name as ``preset`` and ``data_preset``."""
    return {**PRESETS[preset].train, "preset": preset, "data_preset": preset}
