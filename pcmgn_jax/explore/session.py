"""The explorer's state: a run's surrogates and baselines, and what each says about one design.

    ex = Explorer("runs/cpu")           # RunError with a clear message when the run cannot be opened
    ex.names, ex.params                 # the scene parameters (a design's, or a scene family's) and their box
    d = ex.design(ex.start)             # a data.family.Design (the family's canonical row, or the design layers)
    p = ex.predict(d)                   # {predictor: Prediction} at a Design or slider values x (P,) [SI], cached
    v = ex.view(d, frame=12, show="kriging")

What is fitted once (``Explorer.__init__``), so a slider move only predicts: the run's MGN (checkpoint
loaded, rollout compiled by one warm-up rollout), and every baseline the explorer offers (the registry's
kinds with ``explore``, :data:`pcmgn_jax.surrogates.kinds.KINDS`) fitted on the run's training split as the
evaluation fits it (:mod:`pcmgn_jax.explore.predictors`): ``none``/``nearest`` (per node, or the nearest
scene across meshes), ``poly2``/``rbf`` (one shared mesh only), ``kriging`` (the objective surface with its
GP std, and on one shared mesh the field surface for the plots), ``mop`` (the objective surface only) and ``rom``.

Every method that takes a design takes a :class:`~pcmgn_jax.data.family.Design` (its values in :attr:`names`'
order) or the sliders' values x (P,) [SI] (the page's). A design is answered on its own mesh: the training data's
scene with the parameters set (:meth:`Design.scene`: :func:`pcmgn_jax.scene.with_parameters`, or a panel stack's
scene, whose layer list follows its ``.present`` sliders), meshed at the data's preset and cropped to its
region of interest, as a "query" trajectory holding only the initial state (:func:`pcmgn_jax.opt.scenes.query`).
A stack run gets a slider per padded parameter (:mod:`pcmgn_jax.data.stack`) in the family's
order, opens at the paper's six layers at their nominal values, and flags a design outside the family's
ranges by :func:`pcmgn_jax.data.stack.range_warnings`; a baseline that cannot answer a stack (no training
stack of its layers) says so in its row instead of a value. Every field prediction is scored on that mesh by
:func:`pcmgn_jax.metrics.oled_objective_of` (docs/design.md §8), the truth of a solver check too.

Units: SI in and out (parameters, fields); objectives in MPa; the page shows µm, mm, m/s and MPa. The page's
text and figures are :mod:`pcmgn_jax.explore.page`; the vocabulary (Prediction, Truth, View, a slider's
Parameter) :mod:`pcmgn_jax.explore.types`.
"""
from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from pcmgn_jax import metrics
from pcmgn_jax.config import TrainConfig
from pcmgn_jax.data.family import Design
from pcmgn_jax.data.layout import load_manifest
from pcmgn_jax.data.splits import load_splits
from pcmgn_jax.data.stack import nominal, range_warnings, stack_layer_count
from pcmgn_jax.eval.baselines import READING_KEYS
from pcmgn_jax.eval.ensemble import ResidualSpread
from pcmgn_jax.explore.page import Page
from pcmgn_jax.explore.predictors import fit_predictor, predict_one
from pcmgn_jax.explore.types import (
    CACHE_DESIGNS,
    DEFAULT_LIVE_SECONDS,
    LABELS,
    OTHER_LIVE_SECONDS,
    PREDICTORS,
    Cache,
    Prediction,
    RunError,
    Truth,
    design_key,
    has_checkpoint,
    parameter,
)
from pcmgn_jax.opt.problem import DesignBox
from pcmgn_jax.opt.scenes import design_at, family_of, is_stack, query, solve_scene
from pcmgn_jax.scene import Scene
from pcmgn_jax.surrogates.inputs import TrainingScenes, shared_mesh
from pcmgn_jax.surrogates.kinds import KINDS, by_rank
from pcmgn_jax.surrogates.objective import objective_of_fields
from pcmgn_jax.surrogates.registry import fit
from pcmgn_jax.trajectory import Trajectory

DEFAULT_KINDS = tuple(k for k in PREDICTORS if KINDS[k].baseline)   # the baselines an Explorer fits by default


class Explorer(Page):
    """A run opened for exploration (module docstring). ``which``: the checkpoint ('best' | 'periodic');
    ``mgn``: load the run's model (False: baselines only); ``reading``: the objective's reading
    (:data:`pcmgn_jax.metrics.OBJECTIVES`); ``kinds``: the baselines to fit; ``log``: progress lines;
    ``mgn_spread``: roll the MGN out on the training scenes once at load, so that each of its predictions
    carries the std of a GP of its objective residuals there (:class:`pcmgn_jax.eval.ensemble.ResidualSpread`)."""

    def __init__(self, workdir, *, which: str = "best", mgn: bool = True, reading: str = metrics.DEFAULT_OBJECTIVE,
                 kinds: Sequence[str] = DEFAULT_KINDS, log: Callable[[str], None] = print, mgn_spread: bool = False):
        if reading not in metrics.OBJECTIVES:
            raise RunError(f"objective must be one of {metrics.OBJECTIVES}, got {reading!r}")
        self.run = Path(workdir)
        if not (self.run / "config.json").is_file():
            raise RunError(f"{self.run}: no config.json, not a training run directory (make one with "
                           f"`python -m experiments.train --workdir {self.run}`)")
        self.cfg = TrainConfig.load(self.run / "config.json")
        try:
            self.train, _, _ = load_splits(self.cfg.resolved_dataset_dir, n_train=self.cfg.n_train, n_val=0, n_test=0)
        except ValueError as err:
            raise RunError(f"{self.run}: cannot read its training data: {err}") from None
        self.reading, self.which, self.log = reading, which, log
        self.ref = self.train[0]
        self.scene0 = Scene.from_dict(self.ref.meta["scene"])
        self.preset = (self.ref.meta.get("solver") or {}).get("preset")
        names = list(self.ref.meta.get("part_names") or self.scene0.part_names)
        if "OLED" not in names:
            raise RunError(f"{self.run}: the scene has no part named 'OLED' ({names}): no objective to explore")
        self.fam = family_of(self.ref)
        self.stack = is_stack(self.fam)
        self.part = None if self.stack else names.index("OLED")   # a stack's OLED index varies: found by name
        self.scenes = TrainingScenes(self.train)
        # the sliders in the family's order (its rows' names), the training samples (B, P) [SI] likewise
        order = list(self.fam.names) if self.fam is not None and set(self.fam.names) == set(self.scenes.names) \
            else list(self.scenes.names)
        self.names = tuple(order)
        self.samples = self.scenes.x[:, [list(self.scenes.names).index(n) for n in order]]
        self.params = [parameter(n, *box) for n, box in zip(self.names, self._box())]
        # the page opens at the box centre; a stack at the paper's six layers, nominal (pcmgn_jax.data.stack)
        centre = {**{p.name: (p.low + p.high) / 2 for p in self.params}, **(nominal() if self.stack else {})}
        self.start = np.array([centre[n] for n in self.names])
        self.family = bool(self.ref.meta.get("scene_params"))
        self.shared = shared_mesh(self.train)
        self.notes: list[str] = []
        if self.preset is None:
            self.notes.append("the training data are not solver-generated (no meta.solver.preset): every design is "
                              "drawn on the first training mesh, and the solver check is off")
        self._mgn_lock = threading.Lock()      # one MGN rollout at a time (the surrogate grows its buffers)
        self._solver_lock = threading.Lock()   # one solver run at a time
        self._pred = Cache(CACHE_DESIGNS)     # design key -> {predictor: Prediction}
        self._truth = Cache(CACHE_DESIGNS)    # design key -> Truth
        self._queries = Cache(4 * CACHE_DESIGNS)  # design key -> query trajectory
        self.latest: tuple | None = None       # the design the page asked for last (see predict_rest)
        self.test_errors = self._test_errors()
        self.models, self.skipped = {}, {}
        t0 = time.perf_counter()
        for kind in kinds:
            try:
                self.models[kind] = self._fit(kind)
            except ValueError as err:
                self.skipped[kind] = str(err)
        log(f"fitted {len(self.models)} baselines on {len(self.train)} training trajectories "
            f"in {time.perf_counter() - t0:.1f} s")
        self.mgn_seconds = None
        self._mgn_spread = None
        if mgn:
            self._load_mgn(spread=mgn_spread)
        else:
            self.skipped["mgn"] = "not loaded (--no_mgn)"
        self.default = next((k for k in by_rank(self.models) if not KINDS[k].floor), None)
        if self.default is None:
            raise RunError(f"{self.run}: no predictor applies to this run: {self.skipped}")
        self.seconds = self._time_predictors()
        self.live = [k for k in self.available
                     if self.seconds[k] <= (DEFAULT_LIVE_SECONDS if k == self.default else OTHER_LIVE_SECONDS)]
        slow = [k for k in self.available if k not in self.live]
        if slow:
            self.notes.append("a slider move shows the fast predictors at once; " + ", ".join(
                f"{LABELS[k]} ({self.seconds[k]:.2g} s per design here)" for k in slow) +
                " follow for the latest design (their rows say 'computing ...' until then)" +
                ("; a design whose mesh falls in a new size bucket compiles the MGN's rollout first (tens of "
                 "seconds, once per bucket)" if "mgn" in slow and not self.shared else ""))
        first = self.predict(self.start, self.live)
        kinds = [k for k in self._field_kinds() if k in first and first[k].vm is not None]
        # the page opens at the frame where the first field predictor's OLED section reading peaks
        self.start_frame = int(np.argmax(self.objective_history(self.query(self.start), first[kinds[0]].vm))) \
            if kinds else 0

    # ---- loading -------------------------------------------------------------------------------------

    def _time_predictors(self) -> dict[str, float]:
        """{predictor: seconds per design, warm}: each baseline at a design beside the box centre (its first
        call may import or build things), the MGN's rollout time of its warm-up (compilation excluded)."""
        probe = self.start + 0.01 * np.array([p.high - p.low for p in self.params])
        self.predict(self.start, [k for k in self.available if k != "mgn"])
        got = self.predict(probe, [k for k in self.available if k != "mgn"])
        out = {k: p.seconds for k, p in got.items()}
        if "mgn" in self.models:
            out["mgn"] = self.mgn_seconds
        return out

    def _box(self) -> list[tuple[float, float]]:
        """Per parameter the training box [SI]: the range the dataset's designs were drawn from (its
        manifest: a scene family's parameter ranges, or the Latin hypercube's bounds), else the span of
        the training samples (an imported dataset)."""
        lo, hi = self.samples.min(0), self.samples.max(0)
        manifest = load_manifest(Path(self.cfg.resolved_dataset_dir)) or {}
        ranges = {n: (a, b) for n, a, b in ((manifest.get("family") or {}).get("parameters")
                                             or (self.fam.parameters if self.fam is not None else []))}
        origin = ((manifest.get("splits") or {}).get("train") or {}).get("origin") or {}
        if origin.get("kind") == "lhs" and not ranges:
            ranges = {n: (origin["low_m"], origin["high_m"]) for n in manifest.get("design_layers") or ()}
        return [tuple(ranges.get(n, (a, b))) for n, a, b in zip(self.names, lo, hi)]

    def _test_errors(self) -> dict:
        """{predictor: (mean, worst) objective error on the test split [%]} from RUN/eval/metrics.json."""
        path = self.run / "eval" / "metrics.json"
        if not path.is_file():
            self.notes.append(f"{path} is missing: the test-split errors beside each predictor appear after "
                              f"`python -m experiments.evaluate --workdir {self.run}`")
            return {}
        m = json.loads(path.read_text())
        key = READING_KEYS.get(self.reading)
        if key is None:
            return {}
        out = {}
        for name, src in [("mgn", m)] + list(m.get("baselines", {}).items()):
            if f"{key}_rel_error_pct_mean" in src:
                out[name] = (src[f"{key}_rel_error_pct_mean"], src[f"{key}_rel_error_pct_max"])
        return out

    def _fit(self, kind: str):
        return fit_predictor(kind, self.train, reading=self.reading, part=self.part, shared=self.shared)

    def _load_mgn(self, spread: bool = False) -> None:
        if not has_checkpoint(self.run):
            self.skipped["mgn"] = f"no checkpoint in {self.run / 'checkpoints'}"
            self.notes.append(f"{self.run} has no checkpoint: the run's MGN is not shown, the baselines are "
                              f"(train it with `python -m experiments.train --workdir {self.run}`)")
            return
        try:
            model = fit("mgn", self.train, workdir=self.run, ref=self.ref, which=self.which, batch=1)
        except Exception as err:  # an unreadable checkpoint is reported on the page, the baselines still work
            self.skipped["mgn"] = f"the checkpoint could not be loaded: {type(err).__name__}: {err}"
            self.notes.append(f"the MGN is not shown: {self.skipped['mgn']}")
            return
        self.models["mgn"] = model
        t0 = time.perf_counter()
        self.log("compiling the MGN rollout (one warm-up rollout) ...")
        self.predict(self.start, ["mgn"])
        self.mgn_seconds = float(model.rollout_seconds)
        self.log(f"MGN ready in {time.perf_counter() - t0:.1f} s; one rollout takes {self.mgn_seconds:.2f} s")
        if spread:
            t0 = time.perf_counter()
            self.log(f"the MGN on its {len(self.train)} training scenes (its ± comes from its residuals there) ...")
            _, vms = model.rollout_trajectories(self.train)
            f = objective_of_fields(self.train, vms, part=self.part, reading=self.reading)
            self._mgn_spread = ResidualSpread(self.train, f, reading=self.reading, part=self.part)
            self._pred = Cache(CACHE_DESIGNS)   # the warm-up's prediction was made without the ±
            self.log(f"MGN ± ready in {time.perf_counter() - t0:.1f} s (training residual rms "
                     f"{np.sqrt(np.mean(self._mgn_spread.residual_mpa ** 2)):.3g} MPa)")

    # ---- designs -------------------------------------------------------------------------------------

    @property
    def available(self) -> list[str]:
        return [k for k in PREDICTORS if k in self.models]

    @property
    def deferred(self) -> list[str]:
        """The predictors too slow to run at once on a slider move (:meth:`predict_rest` runs them)."""
        return [k for k in self.available if k not in self.live]

    def _field_kinds(self) -> list[str]:
        """The predictors in the order the page offers their fields (those that predicted some): the default
        first, 'none' last."""
        return sorted(by_rank(self.models), key=lambda k: k != self.default)

    def values(self, design) -> np.ndarray:
        """(P,) [SI] in :attr:`names`' order of a :class:`~pcmgn_jax.data.family.Design` (ValueError naming a
        parameter it lacks), or of slider values x (P,) as given."""
        if not isinstance(design, Design):
            return np.asarray(design, float)
        row = design.row
        missing = [n for n in self.names if n not in row]
        if missing:
            raise ValueError(f"{design.label()}: no value for {missing} (the run's parameters: {list(self.names)})")
        return np.array([row[n] for n in self.names])

    def design(self, x) -> Design:
        """The :class:`~pcmgn_jax.data.family.Design` of slider values x (P,) [SI] (or a Design): the family's
        canonical row (:func:`pcmgn_jax.opt.scenes.design_at`), else the design layers' thicknesses."""
        return design_at(self.names, self.values(x), self.fam)

    def scene_at(self, x):
        """The scene of a design (a :class:`pcmgn_jax.scene.Scene`; module docstring)."""
        return self.design(x).scene(self.scene0)

    def query(self, x) -> Trajectory:
        """A design as a trajectory on its own mesh holding the initial state (module docstring)."""
        key = design_key(self.values(x))
        if (q := self._queries.get(key)) is not None:
            return q
        return self._queries.put(key, query(self.design(x), self.scene0, self.ref, self.preset, record=self.family))

    def oled(self, traj) -> int:
        """The OLED's part id in ``traj`` (a query's or the solver's; a stack's varies with its layers)."""
        return self.part if self.part is not None else list(traj.meta["part_names"]).index("OLED")

    def flags(self, x) -> list[str]:
        """Why x (P,) [SI] is outside the training box (one line per parameter; [] inside), or outside the
        span of the training samples (where the regressions extrapolate), and, for a design of the
        scene's design layers, outside the optimiser's problem (:class:`~pcmgn_jax.opt.problem.DesignBox`)."""
        x = self.values(x)
        lo, hi = self.samples.min(0), self.samples.max(0)
        row = self.design(x).row if self.stack else {}
        out = []
        for p, v, a, b in zip(self.params, x, lo, hi):
            slot, _, what = p.name.partition(".")
            if what != "present" and row.get(f"{slot}.present", 1.0) < 0.5:
                continue                  # a stack's absent layer: its sliders are not part of the design
            show = p.text
            if p.outside(v):
                how = "extrapolated" if p.varied else "training held it fixed: answered as if unchanged"
                out.append(f"OUT OF THE TRAINING BOX: {p.label} = {show(v)} outside {show(p.low, p.high)} ({how})")
            elif v < a - 1e-9 * abs(b) or v > b + 1e-9 * abs(b):
                out.append(f"{p.label} = {show(v)} is inside the box but outside the training samples' span "
                           f"{show(a, b)}: the regressions extrapolate")
        if self.stack:
            out += range_warnings("this design", row)
            trained = sorted({stack_layer_count(dict(zip(self.names, r))) for r in self.samples})
            if stack_layer_count(row) not in trained:
                out.append(f"a stack of {stack_layer_count(row)} layers: the training stacks have {trained} "
                           "(a layer count never trained on)")
        if not self.family and len(x) == len(self.scene0.design_layers):
            problem = DesignBox(dim=len(x))
            if problem.violation(x)[0] > 1e-12:
                out.append(f"outside the optimiser's problem: {problem.low * 1e6:g}–{problem.high * 1e6:g} µm "
                           f"each, sum {problem.sum_low * 1e6:g}–{problem.sum_high * 1e6:g} µm "
                           f"(sum here {x.sum() * 1e6:.1f} µm)")
        return out

    def out_of_box(self, x) -> list[bool]:
        """Per parameter: x (P,) [SI] outside the training box [low, high]."""
        return [p.outside(v) for p, v in zip(self.params, self.values(x))]

    # ---- predictions ---------------------------------------------------------------------------------

    def _weights(self, q):
        return metrics.objective_weights(q.points, q.cells, q.cell_part, q.node_part, part=self.oled(q),
                                         reading=self.reading)

    def objective_history(self, q, vm) -> np.ndarray:
        """(T,) the objective's section reading at each frame [MPa] (docs/design.md §8 averages it over the
        window) of von Mises vm (T, N) [Pa] on the query's mesh."""
        return np.asarray(metrics.oled_objective(np.asarray(vm)[:, None, :], self._weights(q), reading=self.reading))

    def _predict_one(self, kind: str, q) -> Prediction:
        mgn = kind == "mgn"
        t0 = time.perf_counter()
        try:
            return predict_one(kind, self.models[kind], q, reading=self.reading, part=self.part,
                               lock=self._mgn_lock if mgn else None, spread=self._mgn_spread if mgn else None)
        except ValueError as err:   # a refusal by name (e.g. no training stack of these layers): the row says it
            return Prediction(kind, None, None, None, None, time.perf_counter() - t0, str(err))

    def predict(self, x, kinds: Sequence[str] | None = None) -> dict[str, Prediction]:
        """{predictor: Prediction} at x (P,) [SI] for ``kinds`` (default :attr:`live`), computed once
        per design (the last :data:`CACHE_DESIGNS` designs are kept)."""
        x = self.values(x)
        key = design_key(x)
        have = self._pred.get(key)
        if have is None:
            have = self._pred.put(key, {})
        q = self.query(x)
        for kind in (self.live if kinds is None else kinds):
            if kind not in have and kind in self.models:
                have[kind] = self._predict_one(kind, q)
        return dict(have)

    def ask(self, x) -> list[str]:
        """A slider move to x (P,) [SI]: x becomes the latest design, the :attr:`live` predictors run; its flags."""
        x = self.values(x)
        self.latest = design_key(x)
        self.predict(x)
        return self.flags(x)

    def predict_rest(self, x) -> bool:
        """The :attr:`deferred` predictors at x when x is still the latest design asked for (work queued
        behind newer slider moves is skipped); True when a prediction was made."""
        x = self.values(x)
        todo = [k for k in self.deferred if k not in self._pred.get(design_key(x), {})]
        if not todo or (self.latest is not None and design_key(x) != self.latest):
            return False
        self.predict(x, todo)
        return True

    def check(self, x) -> Truth:
        """The built-in solver at x (P,) [SI] on the data's preset (seconds on the cpu preset), cached."""
        x = self.values(x)
        key = design_key(x)
        if (known := self._truth.get(key)) is not None:
            return known
        if self.preset is None:
            raise ValueError("the solver check needs solver-generated training data (meta.solver.preset)")
        scene = self.scene_at(x)
        t0 = time.perf_counter()
        with self._solver_lock:
            traj, result = solve_scene(scene, self.preset)
        force = np.concatenate([[0.0], np.asarray(result.force[0])[:, -1]])
        truth = Truth(traj, force, float(metrics.oled_objective_of(traj, part=self.part, reading=self.reading)),
                      time.perf_counter() - t0)
        return self._truth.put(key, truth)

    def truth(self, x) -> Truth | None:
        """The solver check at x if one was run."""
        return self._truth.get(design_key(self.values(x)))
