"""A model of only the question: a scene's reference graph -> per-node time fields, in one pass.

    cfg = OnePassConfig(num_steps=2000, preset="stack", part_identity="role", origin="contact_top", ...)
    d = design_inputs(cfg, traj, radius=r, capacity=c)     # the design's graph at its initial state (frame 0)
    y = time_targets(traj)                                 # (N, 3) what the model learns, physical units
    run = load(workdir)                                    # a trained run (pcmgn_jax.train.onepass)
    fields = run.predict([d, ...])                         # one (N_b, 3) array per design, physical

No rollout. The input is the graph the MGN sees of a design's initial state (frame 0: the reference mesh, zero
displacement, the ball's drop velocity): the same construction (:func:`pcmgn_jax.mgn.rollout.input_graph` of
:func:`pcmgn_jax.mgn.inputs.graph_inputs`, with the design's scene features), the same normalisation of the inputs
(:func:`pcmgn_jax.mgn.normalization.normalize_graph`) and the same encode-process-decode network
(:class:`pcmgn_jax.mgn.model.EncodeProcessDecode`, its decoder giving 3 channels per node). What tells the parts
apart is the rollout MGN's rule for the dataset's preset (``preset``, ``scene_features``, ``part_identity``,
``origin``: :func:`pcmgn_jax.train.onepass.for_dataset` reads them from the dataset's manifest): the box's and the
scene family's one-hot of every part with the layer thicknesses as node inputs, the stacks' six role node types
(:data:`pcmgn_jax.mgn.graphs.ROLES`) with each node's own material, thickness and depth and heights from the
contact layer's top, so stacks of 5, 6 and 7 layers share one input width. The outputs (:data:`TARGETS`), per node
over the T frames of the window (frame 0 included, as the objective averages them):

- ``mean_von_mises``   time-mean von Mises stress [Pa]
- ``peak_von_mises``   the largest von Mises stress over the frames [Pa]
- ``peak_deflection``  the largest displacement magnitude |u| over the frames [m]

Each target is normalised per node type (part or role) by its mean and std over the training designs' nodes of
that type (``Stats.target_mean/std`` rows, :func:`pcmgn_jax.mgn.normalization.normalize_target`): O(1) in every
part, whether the part's stress is the cover glass's ~100 MPa or the OLED's ~1 MPa.

The objective follows from the predicted time-mean field by the one definition
(:func:`pcmgn_jax.metrics.oled_objective`, on each design's own mesh): every linear reading (``area_mean``,
``node_mean``, ``disc_mean``) is a weighted section sum averaged over frames, so it equals the same reading of the
time-mean field (one "frame"); ``peak`` (max over frames and section nodes) equals the max of the peak field over
the section.

Loss of one design (normalised units): sum_i w_i |e_i|^2 / 3 over its nodes (w: each part counts alike,
:func:`pcmgn_jax.train.setup.loss_weights`) plus ``lambda_obj`` x (relative error of its ``area_mean``
objective)^2 from the predicted time-mean field; the step's loss is the mean over the batch's designs.
Designs of any meshes are batched as one padded disjoint union of a static size (:mod:`pcmgn_jax.mgn.onepass_union`),
so a scene family's or a stack family's designs (each its own mesh) train together and a step compiles once.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np
import orbax.checkpoint as ocp

from pcmgn_jax.mgn import checkpoint, onepass_union as union
from pcmgn_jax.mgn.formulation import Formulation, Origin, PartIdentity
from pcmgn_jax.mgn.inputs import graph_inputs
from pcmgn_jax.mgn.model import EncodeProcessDecode
from pcmgn_jax.mgn.normalization import Accumulator, Stats, TypedAccumulator
from pcmgn_jax.mgn.scene_features import across_part_channels
from pcmgn_jax.presets import PRESET_NAMES

TARGETS = ("mean_von_mises", "peak_von_mises", "peak_deflection")   # [Pa], [Pa], [m] per node
CONFIG_FILE = "onepass.json"


@dataclass(frozen=True)
class OnePassConfig:
    """A one-pass run's settings (written to ``workdir/onepass.json``; ``--resume`` refuses a change)."""

    dataset_dir: str = ""
    preset: str = ""                               # the dataset's preset (its manifest's; "" an imported dataset)
    n_train: int = 12
    n_val: int = 2
    n_test: int = 6
    latent_size: int = 64
    mlp_layers: int = 2
    message_passing_steps: int = 8
    reach: str = "local"                           # local | multiscale | attention (EncodeProcessDecode)
    features: str = "strain"                       # the MGN's edge / node feature set (graphs.node_features)
    scene_features: tuple[str, ...] = ("layer_thickness",)  # the preset's (manifest) unless given
    part_identity: PartIdentity = "type"           # the preset's (manifest): type | material | role (Formulation)
    origin: Origin = "mesh"                        # the preset's (manifest): mesh | contact_top | support_top
    num_steps: int = 2000
    batch_graphs: int = 4                          # designs per step (capped at the training designs)
    learning_rate: float = 1e-3
    lr_decay_rate: float = 0.1                     # lr0 * rate ** (step / num_steps), the MGN's schedule
    ema_decay: float = 0.99                        # the parameters' moving average, validated and kept
    lambda_obj: float = 100.0                      # weight of the squared relative objective error
    objective_part: str = "OLED"                   # the part whose section mean is the objective
    seed: int = 0
    log_every: int = 50
    val_every: int = 100
    ckpt_every: int = 200
    max_to_keep: int = 2

    def __post_init__(self):
        object.__setattr__(self, "scene_features", tuple(self.scene_features))
        for name in ("latent_size", "mlp_layers", "num_steps", "batch_graphs", "log_every", "val_every",
                     "ckpt_every", "max_to_keep", "n_train"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise ValueError(f"onepass config: {name}={getattr(self, name)!r} must be an integer >= 1")
        if self.message_passing_steps < 0 or self.n_val < 0 or self.n_test < 0:
            raise ValueError("onepass config: message_passing_steps, n_val and n_test must be >= 0")
        if not (self.learning_rate > 0 and 0 < self.lr_decay_rate <= 1 and 0 <= self.ema_decay < 1
                and self.lambda_obj >= 0):
            raise ValueError(f"onepass config: learning_rate={self.learning_rate} must be > 0, lr_decay_rate="
                             f"{self.lr_decay_rate} in (0, 1], ema_decay={self.ema_decay} in [0, 1), lambda_obj="
                             f"{self.lambda_obj} >= 0")
        if self.preset and self.preset not in PRESET_NAMES:
            raise ValueError(f"onepass config: preset={self.preset!r} must be one of {PRESET_NAMES} (or '')")
        self.formulation  # validates features / scene_features / reach / part_identity / origin

    @property
    def formulation(self) -> Formulation:
        """The graph construction's settings (a dynamic formulation: the initial state as it is)."""
        return Formulation(features=self.features, scene_features=self.scene_features, reach=self.reach,
                           part_identity=self.part_identity, origin=self.origin)

    def model(self) -> EncodeProcessDecode:
        return EncodeProcessDecode(output_size=len(TARGETS), latent_size=self.latent_size, mlp_layers=self.mlp_layers,
                                   message_passing_steps=self.message_passing_steps, reach=self.reach)

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "scene_features": list(self.scene_features)}

    @classmethod
    def from_dict(cls, data: dict, where: str = "onepass config") -> "OnePassConfig":
        unknown = sorted(set(data) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise ValueError(f"{where}: unknown field(s) {unknown}")
        return cls(**data)

    @classmethod
    def load(cls, workdir: str | Path) -> "OnePassConfig":
        path = Path(workdir) / CONFIG_FILE
        if not path.is_file():
            raise checkpoint.MissingRun(f"{path}: no such file; {workdir} is not a one-pass run (make one with "
                                        f"`python -m experiments.onepass --workdir {workdir} ...`)")
        try:
            return cls.from_dict(json.loads(path.read_text()), str(path))
        except json.JSONDecodeError as err:
            raise ValueError(f"{path}: not JSON ({err})") from None


def time_targets(traj) -> np.ndarray:
    """(N, 3) float64 [Pa, Pa, m] of a trajectory (:data:`TARGETS`): the time mean and the max over its T frames of
    the von Mises stress, the max over the frames of the displacement magnitude."""
    vm = np.asarray(traj.von_mises, np.float64)
    defl = np.linalg.norm(np.asarray(traj.displacement, np.float64), axis=-1)
    return np.stack([vm.mean(0), vm.max(0), defl.max(0)], axis=-1)


def part_id(traj, name: str) -> int:
    """The id of the part called ``name`` in a trajectory's ``meta['part_names']``; ValueError naming both."""
    names = list(traj.meta.get("part_names") or [])
    if name not in names:
        raise ValueError(f"trajectory {traj.meta.get('name', '?')}: no part named {name!r} in {names}")
    return names.index(name)


def design_inputs(cfg: OnePassConfig, traj, *, radius: float | None = None, capacity: int | None = None) -> dict:
    """The static graph inputs of one design at its initial state (frame 0): topology with its scene features,
    contact index (``radius`` [m], default the MGN's; ``capacity``, default sized on frame 0), reference points
    and the initial displacement [m] and velocity [m/s]."""
    u0 = np.asarray(traj.displacement[0], np.float32)
    inp = graph_inputs(traj, traj.meta["scene"], scene_features=cfg.scene_features, radius=radius,
                       capacity=capacity, positions=[np.asarray(traj.points)[None] + u0[None]],
                       levels=cfg.formulation.hierarchy_levels, identity=cfg.part_identity)
    return {**inp._asdict(), "u0": u0, "v0": np.asarray(traj.velocity[0], np.float32)}


def compute_stats(cfg: OnePassConfig, designs, targets, *, scene: dict | None = None) -> Stats:
    """Input statistics (the MGN's layout and rules: per node type with ``per_part``, a part's own ``material``
    over all nodes) of the training designs' graphs, and the targets' per-type mean/std (``target_mean/std``
    [T, 3]); ``targets``: (N_b, 3) per design. The designs' graphs (any meshes) are built in padded unions of one
    size (:mod:`pcmgn_jax.mgn.onepass_union`, one compilation) and only their real nodes and edges are counted.
    ``scene``: a training design's scene dict (the widths of its scene features, for where ``material`` lies)."""
    form = cfg.formulation
    n_types = designs[0]["topology"].n_node_types
    widths = sorted({d["topology"].n_node_types for d in designs})
    if widths != [n_types]:
        raise ValueError(f"one-pass statistics: the designs have {widths} node types; designs of different parts "
                         "train together only with part_identity='role'")
    slots = min(cfg.batch_graphs, len(designs))
    sizes = union.union_sizes(designs, slots)
    raw = _jitted("raw", cfg, lambda: lambda x: union.raw_graph(form, x))
    acc: dict = {}
    for ids in union.chunks(len(designs), slots):
        u = union.make_union([designs[i] for i in ids], sizes)
        g = raw(u)
        nt, mask = np.asarray(u.graph.topology.node_type), np.asarray(u.graph.layout.node_mask)
        nodes, mesh, cont = np.asarray(g.nodes)[:, n_types:], g.edges["mesh"], g.edges["contact"]
        if not acc:
            acc = {"node": TypedAccumulator(n_types, nodes.shape[1]),
                   "mesh": TypedAccumulator(n_types, mesh.features.shape[1]),
                   "contact": Accumulator(cont.features.shape[1]), "target": TypedAccumulator(n_types, len(TARGETS))}
        acc["node"].add(nodes, nt, mask)
        acc["mesh"].add(mesh.features, nt[np.asarray(mesh.receivers)], np.asarray(mesh.mask))
        acc["contact"].add(cont.features, np.asarray(cont.mask))
        acc["target"].add(union.node_array(u, [targets[i] for i in ids]), nt, mask)
    sf = designs[0]["topology"].scene_features
    first = nodes.shape[1] - (0 if sf is None else np.shape(sf)[1])   # the scene features: the last channels
    across = [first + i for i in across_part_channels(scene or {}, cfg.scene_features)]
    per_part = form.normalization == "per_part"
    f = lambda a: np.asarray(a, np.float32)  # noqa: E731
    nm, ns = acc["node"].result(per_part, across)
    mm, ms = acc["mesh"].result(per_part)
    cm, cs = acc["contact"].result(default_std=float(designs[0]["index"].radius))
    tm, ts = acc["target"].result(True)
    return Stats(f(nm), f(ns), f(mm), f(ms), f(cm), f(cs), f(tm), f(ts), np.zeros(2, np.float32),
                 np.ones(2, np.float32))


class Run(NamedTuple):
    """A trained one-pass run, ready to predict (:func:`load`)."""

    cfg: OnePassConfig
    params: Any
    stats: Stats
    meta: dict      # contact radius and capacity, best validation error, step

    def inputs(self, traj) -> dict:
        """:func:`design_inputs` of a trajectory at the run's contact radius and buffer."""
        return design_inputs(self.cfg, traj, radius=self.meta["contact_radius"], capacity=self.meta["contact_capacity"])

    def predict(self, designs) -> list[np.ndarray]:
        """One (N_b, 3) float64 array of physical fields [Pa, Pa, m] (:data:`TARGETS`) per design, each on its own
        mesh (:func:`predict_fields`)."""
        return predict_fields(self.cfg, self.params, self.stats, designs)


def predict_fields(cfg: OnePassConfig, params, stats: Stats, designs, *, slots: int | None = None) -> list[np.ndarray]:
    """One (N_b, 3) float64 array [Pa, Pa, m] per design (:func:`design_inputs` dicts, any meshes): the designs in
    unions of ``slots`` (default ``cfg.batch_graphs``) of one size for the whole call (one compilation per size)."""
    designs = list(designs)
    if not designs:
        return []
    slots = min(slots or cfg.batch_graphs, len(designs))
    sizes = union.union_sizes(designs, slots)
    out: list[np.ndarray] = []
    for ids in union.chunks(len(designs), slots):
        u = union.make_union([designs[i] for i in ids], sizes)
        out += [np.asarray(f, np.float64) for f in union.split(u, predict_jit(cfg, params, stats, u))]
    return out


def predict_jit(cfg: OnePassConfig, params, stats, u: union.Union):
    """Jitted physical prediction (N, 3) over a union (:mod:`pcmgn_jax.mgn.onepass_union`); one compilation per
    (config, union size)."""
    def make():
        model, form = cfg.model(), cfg.formulation

        def onepass_predict(p, s, x):
            return union.physical(s, x, union.forward(form, model, p, s, x))
        return onepass_predict

    return _jitted("predict", cfg, make)(params, stats, u)


def _jitted(what: str, cfg: OnePassConfig, make):
    """``jax.jit(make())``, made once per (what, config)."""
    if (what, cfg) not in _JITS:
        _JITS[what, cfg] = jax.jit(make())
    return _JITS[what, cfg]


_JITS: dict = {}


def load(workdir: str | Path, which: str = "best") -> Run:
    """A trained one-pass run (its ``onepass.json`` and the ``which`` checkpoint: 'best', falling back to the
    latest periodic one); :class:`pcmgn_jax.mgn.checkpoint.MissingRun` naming what is missing."""
    cfg = OnePassConfig.load(workdir)
    path = checkpoint.checkpoint_dir(workdir, which)
    step = checkpoint.latest_intact(path)
    if step is None:
        raise checkpoint.MissingRun(f"{path}: no readable checkpoint; train it with `python -m experiments.onepass "
                                    f"--workdir {workdir} --resume`")
    step, meta = checkpoint.read_meta(path, step)
    raw = checkpoint.manager(path).restore(step, args=ocp.args.Composite(
        state=ocp.args.StandardRestore(), stats=ocp.args.StandardRestore()))
    params = jax.tree.map(np.asarray, raw["state"]["params"])
    stats = Stats(**{k: np.asarray(raw["stats"][k], np.float32) for k in Stats._fields})
    return Run(cfg, params, stats, {**meta, "step": int(step)})
