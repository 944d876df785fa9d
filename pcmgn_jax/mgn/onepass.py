"""A model of only the question: a scene's reference graph -> per-node time fields, in one pass.

    cfg = OnePassConfig(num_steps=2000)
    d = design_inputs(cfg, traj, radius=r, capacity=c)     # the design's graph at its initial state (frame 0)
    y = time_targets(traj)                                 # (N, 3) what the model learns, physical units
    run = load(workdir)                                    # a trained run (pcmgn_jax.train.onepass)
    fields = run.predict([d, ...])                         # (B, N, 3) physical

No rollout. The input is the graph the MGN sees of a design's initial state (frame 0: the reference mesh, zero
displacement, the ball's drop velocity): the same construction (:func:`pcmgn_jax.mgn.rollout.input_graph` of
:func:`pcmgn_jax.mgn.inputs.graph_inputs`, with the design's scene features, e.g. ``layer_thickness``), the same
normalisation of the inputs (:func:`pcmgn_jax.mgn.normalization.normalize_graph`) and the same encode-process-decode
network (:class:`pcmgn_jax.mgn.model.EncodeProcessDecode`, its decoder giving 3 channels per node). The outputs
(:data:`TARGETS`), per node over the T frames of the window (frame 0 included, as the objective averages them):

- ``mean_von_mises``   time-mean von Mises stress [Pa]
- ``peak_von_mises``   the largest von Mises stress over the frames [Pa]
- ``peak_deflection``  the largest displacement magnitude |u| over the frames [m]

Each target is normalised per node type (part) by its mean and std over the training designs' nodes of that
part (``Stats.target_mean/std`` rows, :func:`pcmgn_jax.mgn.normalization.normalize_target`): O(1) in every
part, whether the part's stress is the cover glass's ~100 MPa or the OLED's ~1 MPa.

The objective follows from the predicted time-mean field by the one definition
(:func:`pcmgn_jax.metrics.oled_objective`): every linear reading (``area_mean``, ``node_mean``, ``disc_mean``)
is a weighted section sum averaged over frames, so it equals the same reading of the time-mean field (one
"frame"); ``peak`` (max over frames and section nodes) equals the max of the peak field over the section.

Loss of one design (normalised units): sum_i w_i |e_i|^2 / 3 over its nodes (w: each part counts alike,
:func:`pcmgn_jax.train.setup.loss_weights`) plus ``lambda_obj`` x (relative error of its ``area_mean``
objective)^2 from the predicted time-mean field; the step's loss is the mean over the batch's designs.
Designs are batched by stacking (one node numbering for all: the built-in solver's meshes of one preset).
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from pcmgn_jax.mgn import checkpoint
from pcmgn_jax.mgn.formulation import Formulation
from pcmgn_jax.mgn.inputs import graph_inputs
from pcmgn_jax.mgn.model import EncodeProcessDecode
from pcmgn_jax.mgn.normalization import (
    Accumulator,
    Stats,
    TypedAccumulator,
    denormalize_output,
    normalize_graph,
    normalize_target,
)
from pcmgn_jax.mgn.rollout import input_graph

TARGETS = ("mean_von_mises", "peak_von_mises", "peak_deflection")   # [Pa], [Pa], [m] per node
CONFIG_FILE = "onepass.json"


@dataclass(frozen=True)
class OnePassConfig:
    """A one-pass run's settings (written to ``workdir/onepass.json``; ``--resume`` refuses a change)."""

    dataset_dir: str = ""
    n_train: int = 12
    n_val: int = 2
    n_test: int = 6
    latent_size: int = 64
    mlp_layers: int = 2
    message_passing_steps: int = 8
    reach: str = "local"                           # local | multiscale | attention (EncodeProcessDecode)
    features: str = "strain"                       # the MGN's edge / node feature set (graphs.node_features)
    scene_features: tuple[str, ...] = ("layer_thickness",)
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
        self.formulation  # validates features / scene_features / reach

    @property
    def formulation(self) -> Formulation:
        """The graph construction's settings (a dynamic formulation: the initial state as it is)."""
        return Formulation(features=self.features, scene_features=self.scene_features, reach=self.reach)

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
                       levels=cfg.formulation.hierarchy_levels)
    return {**inp._asdict(), "u0": u0, "v0": np.asarray(traj.velocity[0], np.float32)}


def raw_graph(cfg: OnePassConfig, d: dict):
    """The raw (SI) input graph of a design (:func:`design_inputs`)."""
    return input_graph(cfg.formulation, d["topology"], d["index"], d["points"], d["u0"], d["v0"])[0]


def compute_stats(cfg: OnePassConfig, designs, targets) -> Stats:
    """Input statistics (the MGN's layout and rules: per node type with ``per_part``) of the training designs'
    graphs, and the targets' per-part mean/std (``target_mean/std`` [T, 3]); ``targets``: (N, 3) per design."""
    form = cfg.formulation
    n_types = designs[0]["topology"].n_node_types
    graphs = [raw_graph(cfg, d) for d in designs]
    acc = {"node": TypedAccumulator(n_types, graphs[0].nodes.shape[1] - n_types),
           "mesh": TypedAccumulator(n_types, graphs[0].edges["mesh"].features.shape[1]),
           "contact": Accumulator(graphs[0].edges["contact"].features.shape[1]),
           "target": TypedAccumulator(n_types, len(TARGETS))}
    for d, g, y in zip(designs, graphs, targets):
        nt = np.asarray(d["topology"].node_type)
        acc["node"].add(np.asarray(g.nodes)[:, n_types:], nt)
        acc["mesh"].add(g.edges["mesh"].features, nt[np.asarray(d["topology"].mesh_receivers)])
        acc["contact"].add(g.edges["contact"].features, np.asarray(g.edges["contact"].mask))
        acc["target"].add(y, nt)
    per_part = form.normalization == "per_part"
    f = lambda a: np.asarray(a, np.float32)  # noqa: E731
    nm, ns = acc["node"].result(per_part)
    mm, ms = acc["mesh"].result(per_part)
    cm, cs = acc["contact"].result(default_std=float(designs[0]["index"].radius))
    tm, ts = acc["target"].result(True)
    return Stats(f(nm), f(ns), f(mm), f(ms), f(cm), f(cs), f(tm), f(ts), np.zeros(2, np.float32),
                 np.ones(2, np.float32))


def normalized_graph(cfg: OnePassConfig, stats: Stats, d: dict):
    """The normalised input graph of a design: what the network reads."""
    return normalize_graph(stats, raw_graph(cfg, d), d["topology"].node_type)


def stack(trees, what: str = "designs"):
    """Stack pytrees of one structure and shape (one node numbering); ValueError naming the first mismatch."""
    shapes = [jax.tree.map(np.shape, t) for t in trees]
    for i, s in enumerate(shapes[1:], 1):
        if s != shapes[0]:
            raise ValueError(f"one-pass model: {what} 0 and {i} differ in graph size or structure; the one-pass "
                             "model batches designs of one node numbering (one mesh topology, as the built-in "
                             "solver meshes one preset), not a scene family of several meshes")
    return jax.tree.map(lambda *a: jnp.stack([jnp.asarray(x) for x in a]), *trees)


def forward(model, params, graphs):
    """Normalised outputs (B, N, 3) of a stack of normalised graphs."""
    return jax.vmap(lambda g: model.apply(params, g))(graphs)


def physical(stats: Stats, node_type, out):
    """(B, N, 3) normalised outputs -> physical [Pa, Pa, m] with each node's part row."""
    return jax.vmap(lambda o: denormalize_output(stats, node_type, o))(out)


def loss_fn(params, model, stats: Stats, graphs, targets, node_type, weights, obj_weights, lambda_obj):
    """The step's loss (module docstring): ``graphs`` stacked (B, ...), ``targets`` (B, N, 3) physical,
    ``weights`` (N,) per node (sum 1), ``obj_weights`` (N,) the ``area_mean`` section weights (sum 1).
    Returns (loss, (data term, objective term)) as scalars."""
    out = forward(model, params, graphs)
    tn = jax.vmap(lambda y: normalize_target(stats, node_type, y))(targets)
    data = jnp.mean(jnp.sum(weights[None, :, None] * (out - tn) ** 2, axis=(1, 2)) / len(TARGETS))
    mean_pred = physical(stats, node_type, out)[..., 0]
    truth = targets[..., 0] @ obj_weights
    rel = (mean_pred @ obj_weights - truth) / jnp.maximum(jnp.abs(truth), 1e-12)
    obj = jnp.mean(rel ** 2)
    return data + lambda_obj * obj, (data, obj)


class Run(NamedTuple):
    """A trained one-pass run, ready to predict (:func:`load`)."""

    cfg: OnePassConfig
    params: Any
    stats: Stats
    meta: dict      # contact radius and capacity, best validation error, step

    def inputs(self, traj) -> dict:
        """:func:`design_inputs` of a trajectory at the run's contact radius and buffer."""
        return design_inputs(self.cfg, traj, radius=self.meta["contact_radius"], capacity=self.meta["contact_capacity"])

    def predict(self, designs) -> np.ndarray:
        """(B, N, 3) float64 physical fields [Pa, Pa, m] (:data:`TARGETS`) of designs of one node numbering."""
        graphs = stack([normalized_graph(self.cfg, self.stats, d) for d in designs])
        return np.asarray(predict_jit(self.cfg, self.params, self.stats, graphs,
                                      jnp.asarray(designs[0]["topology"].node_type)), np.float64)


def predict_jit(cfg: OnePassConfig, params, stats, graphs, node_type):
    """Jitted physical prediction (B, N, 3) of stacked normalised graphs; one compilation per (config, shape)."""
    if cfg not in _JITS:
        model = cfg.model()

        def onepass_predict(p, s, g, nt):
            return physical(s, nt, forward(model, p, g))

        _JITS[cfg] = jax.jit(onepass_predict)
    return _JITS[cfg](params, stats, graphs, node_type)


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
