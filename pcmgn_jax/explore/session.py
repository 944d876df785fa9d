"""The explorer's state: a run's surrogates and baselines, and what each says about one design.

    ex = Explorer("runs/cpu")           # RunError with a clear message when the run cannot be opened
    ex.names, ex.params                 # the scene parameters (a design's, or a scene family's) and their box
    p = ex.predict(x)                   # {predictor: Prediction} at x (P,) [SI], cached per design
    v = ex.view(x, frame=12, show="kriging")

What is fitted once (``Explorer.__init__``), so a slider move only predicts: the run's MGN (checkpoint
loaded, rollout compiled by one warm-up rollout), and every baseline of :mod:`pcmgn_jax.eval.baselines`
fitted on the run's training split as the evaluation fits it: ``none``/``nearest`` (per node, or
:class:`~pcmgn_jax.eval.surrogates.NearestScene` across meshes), ``poly2``/``rbf`` (one shared mesh only),
``kriging`` (the objective surface with its GP std, and on one shared mesh the field surface for the
plots), ``mop`` (the objective surface only) and ``rom``.

A design is answered on its own mesh: the training data's scene with the parameters set
(:func:`pcmgn_jax.scene.with_parameters`), meshed at the data's preset and cropped to its region of
interest, as a "query" trajectory holding only the initial state (the solver's rule,
:func:`pcmgn_jax.sim.initial.initial_velocity`). Every field prediction is scored on that mesh by
:func:`pcmgn_jax.eval.metrics.oled_objective_of` (docs/design.md §8), the truth of a solver check too.

Units: SI in and out (parameters, fields); objectives in MPa; the page shows µm, mm, m/s and MPa.
"""
from __future__ import annotations

import json
import threading
import time
import warnings
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple, Sequence

import numpy as np

from pcmgn_jax.eval import metrics
from pcmgn_jax.eval.baselines import KINDS, READING_KEYS, shared_mesh
from pcmgn_jax.trajectory import Trajectory

PREDICTORS = ("mgn",) + KINDS
LABELS = {"mgn": "MGN (the run's model)", "none": "nothing moves", "nearest": "nearest training design",
          "poly2": "per-node quadratic", "rbf": "per-node RBF", "kriging": "kriging", "mop": "MOP",
          "rom": "POD reduced-order model"}
DEFAULT_LIVE_SECONDS = 0.6  # the default predictor runs at once on a slider move when it takes at most this [s]
OTHER_LIVE_SECONDS = 0.1    # any other predictor too when it takes at most this [s]; slower ones follow the page
WIDEN = 0.25         # the sliders reach this fraction of the training box's span beyond each side
CACHE_DESIGNS = 8    # designs whose predictions (full fields) are kept
SHOW_ORDER = ("mgn", "kriging", "rom", "poly2", "rbf", "nearest", "none")   # whose fields the page shows first


class RunError(ValueError):
    """A run directory the explorer cannot open (the message says what is missing and how to make it)."""


@dataclass(frozen=True)
class Parameter:
    """A slider: scene parameter ``name`` with its training box [low, high] [SI]; the page shows
    ``value * scale`` in ``unit``."""

    name: str
    low: float
    high: float
    unit: str
    scale: float
    label: str

    @property
    def varied(self) -> bool:
        return self.high > self.low

    def outside(self, value: float) -> bool:
        """``value`` [SI] lies outside the training box (beyond round-off)."""
        tol = 1e-9 * max(self.high - self.low, abs(self.high))
        return bool(value < self.low - tol or value > self.high + tol)

    def text(self, *values: float) -> str:
        """Values [SI] on the page: '30 µm', or a range '50–150 µm'."""
        return "–".join(f"{v * self.scale:.4g}" for v in values) + f" {self.unit}"

    def slider_range(self) -> tuple[float, float]:
        """(min, max) of the slider [SI]: the training box widened by ``WIDEN`` of its span (or of the
        value, for a parameter training held fixed) on each side, kept positive."""
        w = WIDEN * ((self.high - self.low) if self.varied else abs(self.low))
        return max(self.low - w, 0.1 * self.low), self.high + w


def parameter(name: str, low: float, high: float) -> Parameter:
    """The slider of scene parameter ``name`` ('ball.radius' [m], 'ball.velocity' [m/s], a layer name
    (its thickness [m])) over the training box [low, high]."""
    if name == "ball.velocity":
        return Parameter(name, low, high, "m/s", 1.0, "drop speed")
    if name == "ball.radius":
        return Parameter(name, low, high, "mm", 1e3, "ball radius")
    return Parameter(name, low, high, "µm", 1e6, f"{name} thickness")


class Prediction(NamedTuple):
    """One predictor's answer at a design."""

    name: str
    objective_mpa: float | None   # the OLED objective [MPa] (None: not applicable, see note)
    std_mpa: float | None         # its uncertainty [MPa]: kriging's GP posterior std, else None
    u: np.ndarray | None          # (T, N, 2) displacement [m] on the design's mesh (None: no fields)
    vm: np.ndarray | None         # (T, N) von Mises [Pa]
    seconds: float                # wall time of the prediction [s]
    note: str = ""                # why there is no value, or what the value is of


class Truth(NamedTuple):
    """The built-in solver's answer at a design (a solver check)."""

    traj: Trajectory              # ROI-cropped trajectory on the design's mesh
    force: np.ndarray             # (T,) contact force on the ball at each frame [N] (0 at t = 0)
    objective_mpa: float          # the OLED objective [MPa]
    seconds: float                # solver wall time [s]


class View(NamedTuple):
    """Everything the page shows for a design (see :meth:`Explorer.view`)."""

    headline: str                 # the default predictor's objective with its uncertainty, or why not
    rows: list                    # one dict per predictor (and the truth): name, label, text, error, test
    flags: list                   # out-of-box messages for this design ([] inside the box)
    notes: list                   # run-level notes (no checkpoint, no metrics, MGN on release, ...)
    show: str                     # whose fields the figures draw ('truth', 'error:<predictor>', or a predictor)
    figures: dict                 # 'field', 'oled', 'history', 'box': Plotly figure dicts


class _Cache:
    """A small thread-safe LRU map (the page's callbacks run in the web server's threads)."""

    def __init__(self, size: int):
        self.size, self.items, self.lock = size, OrderedDict(), threading.Lock()

    def get(self, key, default=None):
        with self.lock:
            if key not in self.items:
                return default
            self.items.move_to_end(key)
            return self.items[key]

    def put(self, key, value):
        with self.lock:
            self.items[key] = value
            self.items.move_to_end(key)
            while len(self.items) > self.size:
                self.items.popitem(last=False)
        return value


def _has_checkpoint(run: Path) -> bool:
    return any(p.name.isdigit() for sub in ("best", "periodic") for p in (run / "checkpoints" / sub).glob("*"))


def _key(x) -> tuple:
    return tuple(float(f"{v:.9g}") for v in np.asarray(x, float))


class Explorer:
    """A run opened for exploration (module docstring). ``which``: the checkpoint ('best' | 'periodic');
    ``mgn``: load the run's model (False: baselines only); ``reading``: the objective's reading
    (:data:`pcmgn_jax.eval.metrics.OBJECTIVES`); ``kinds``: the baselines to fit; ``log``: progress lines;
    ``mgn_spread``: roll the MGN out on the training scenes once at load, so that each of its predictions
    carries the std of a GP of its objective residuals there (:class:`pcmgn_jax.eval.ensemble.ResidualSpread`)."""

    def __init__(self, workdir, *, which: str = "best", mgn: bool = True, reading: str = metrics.DEFAULT_OBJECTIVE,
                 kinds: Sequence[str] = KINDS, log: Callable[[str], None] = print, mgn_spread: bool = False):
        from pcmgn_jax.config import TrainConfig
        from pcmgn_jax.data.splits import load_splits
        from pcmgn_jax.eval.scene_inputs import TrainingScenes
        from pcmgn_jax.scene import Scene

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
        self.part = names.index("OLED")
        self.scenes = TrainingScenes(self.train)
        self.names = self.scenes.names
        self.params = [parameter(n, *box) for n, box in zip(self.names, self._box())]
        self.start = np.array([(p.low + p.high) / 2 for p in self.params])   # the page opens at the box centre
        self.family = bool(self.ref.meta.get("scene_params"))
        self.shared = shared_mesh(self.train)
        self.notes: list[str] = []
        if self.preset is None:
            self.notes.append("the training data are not solver-generated (no meta.solver.preset): every design is "
                              "drawn on the first training mesh, and the solver check is off")
        self._mgn_lock = threading.Lock()      # one MGN rollout at a time (the surrogate grows its buffers)
        self._solver_lock = threading.Lock()   # one solver run at a time
        self._pred = _Cache(CACHE_DESIGNS)     # design key -> {predictor: Prediction}
        self._truth = _Cache(CACHE_DESIGNS)    # design key -> Truth
        self._queries = _Cache(4 * CACHE_DESIGNS)  # design key -> query trajectory
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
        self.default = "mgn" if "mgn" in self.models else next(
            (k for k in ("kriging", "mop", "rom", "poly2", "nearest") if k in self.models), None)
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
        kinds = [k for k in self._field_kinds() if k in first]
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
        from pcmgn_jax.data.layout import load_manifest

        lo, hi = self.scenes.x.min(0), self.scenes.x.max(0)
        manifest = load_manifest(Path(self.cfg.resolved_dataset_dir)) or {}
        ranges = {n: (a, b) for n, a, b in ((manifest.get("family") or {}).get("parameters") or [])}
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
        from pcmgn_jax.eval.response_surfaces import FieldSurface, ObjectiveSurface
        from pcmgn_jax.eval.rom import Rom
        from pcmgn_jax.eval.surrogates import FieldRegression, NearestScene

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if kind in ("kriging", "mop"):
                surface = ObjectiveSurface(kind, self.train, readings=(self.reading,), part=self.part)
                fields = FieldSurface(kind, self.train) if kind == "kriging" and self.shared else None
                return surface, fields
            if kind == "rom":
                return Rom(self.train)
            if self.shared:
                return FieldRegression(kind, self.train)
            if kind in ("none", "nearest"):
                return NearestScene(self.train, zero=kind == "none")
        raise ValueError(f"{kind}: per-node regression needs one shared mesh; this run's meshes differ")

    def _load_mgn(self, spread: bool = False) -> None:
        from pcmgn_jax.eval.surrogates import MGNSurrogate

        if not _has_checkpoint(self.run):
            self.skipped["mgn"] = f"no checkpoint in {self.run / 'checkpoints'}"
            self.notes.append(f"{self.run} has no checkpoint: the run's MGN is not shown, the baselines are "
                              f"(train it with `python -m experiments.train --workdir {self.run}`)")
            return
        try:
            model = MGNSurrogate(self.run, self.ref, which=self.which, batch=1)
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
            from pcmgn_jax.eval.ensemble import ResidualSpread, rollout_objectives
            t0 = time.perf_counter()
            self.log(f"the MGN on its {len(self.train)} training scenes (its ± comes from its residuals there) ...")
            _, vms = model.rollout_trajectories(self.train)
            f = rollout_objectives(self.train, vms, self.part, self.reading)
            self._mgn_spread = ResidualSpread(self.train, f, reading=self.reading, part=self.part)
            self._pred = _Cache(CACHE_DESIGNS)   # the warm-up's prediction was made without the ±
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
        """Predictors with fields, in the order the page offers them: the default first, 'none' last."""
        has = [k for k in SHOW_ORDER if k in self.models and not (k == "kriging" and self.models[k][1] is None)]
        return sorted(has, key=lambda k: k != self.default)

    def scene_at(self, x):
        """The training scene with the parameters x (P,) [SI] set (a :class:`pcmgn_jax.scene.Scene`)."""
        from pcmgn_jax.scene import with_parameters
        return with_parameters(self.scene0, dict(zip(self.names, np.asarray(x, float))))

    def query(self, x) -> Trajectory:
        """The design x (P,) [SI] as a trajectory on its own mesh holding the initial state (module docstring)."""
        key = _key(x)
        if (q := self._queries.get(key)) is not None:
            return q
        from pcmgn_jax.sim.initial import initial_velocity
        from pcmgn_jax.sim.mesh import build_mesh, roi

        scene = self.scene_at(x)
        if self.preset is None:
            mesh = self.ref
        else:
            mesh, _ = roi(build_mesh(scene, self.preset), self.preset)
        T, N = self.ref.n_frames, len(mesh.points)
        v = np.zeros((T, N, 2))
        v[0] = initial_velocity(scene, mesh.node_part)
        meta = {"scene": scene.to_dict(), "part_names": list(scene.part_names), "name": "the explored design",
                "design": {n: float(t) for n, t in zip(scene.design_layers, scene.design)}}
        if self.family:
            meta["scene_params"] = {n: float(t) for n, t in zip(self.names, np.asarray(x, float))}
        q = Trajectory(points=np.asarray(mesh.points, np.float64), cells=mesh.cells, cell_part=mesh.cell_part,
                       node_part=mesh.node_part, node_type=mesh.node_type, times=np.asarray(self.ref.times),
                       displacement=np.zeros((T, N, 2)), velocity=v, von_mises=np.zeros((T, N)), meta=meta)
        return self._queries.put(key, q)

    def flags(self, x) -> list[str]:
        """Why x (P,) [SI] is outside the training box (one line per parameter; [] inside), or outside the
        span of the training samples (where the regressions extrapolate), and, for a design of the
        scene's design layers, outside the optimiser's problem (:class:`~pcmgn_jax.opt.problem.DesignBox`)."""
        from pcmgn_jax.opt.problem import DesignBox

        x = np.asarray(x, float)
        lo, hi = self.scenes.x.min(0), self.scenes.x.max(0)
        out = []
        for p, v, a, b in zip(self.params, x, lo, hi):
            show = p.text
            if p.outside(v):
                how = "extrapolated" if p.varied else "training held it fixed: answered as if unchanged"
                out.append(f"OUT OF THE TRAINING BOX: {p.label} = {show(v)} outside {show(p.low, p.high)} ({how})")
            elif v < a - 1e-9 * abs(b) or v > b + 1e-9 * abs(b):
                out.append(f"{p.label} = {show(v)} is inside the box but outside the training samples' span "
                           f"{show(a, b)}: the regressions extrapolate")
        if not self.family and len(x) == len(self.scene0.design_layers):
            problem = DesignBox(dim=len(x))
            if problem.violation(x)[0] > 1e-12:
                out.append(f"outside the optimiser's problem: {problem.low * 1e6:g}–{problem.high * 1e6:g} µm "
                           f"each, sum {problem.sum_low * 1e6:g}–{problem.sum_high * 1e6:g} µm "
                           f"(sum here {x.sum() * 1e6:.1f} µm)")
        return out

    def out_of_box(self, x) -> list[bool]:
        """Per parameter: x (P,) [SI] outside the training box [low, high]."""
        return [p.outside(v) for p, v in zip(self.params, np.asarray(x, float))]

    # ---- predictions ---------------------------------------------------------------------------------

    def _weights(self, q):
        return metrics.objective_weights(q.points, q.cells, q.cell_part, q.node_part, part=self.part,
                                         reading=self.reading)

    def objective_history(self, q, vm) -> np.ndarray:
        """(T,) the objective's section reading at each frame [MPa] (docs/design.md §8 averages it over the
        window) of von Mises vm (T, N) [Pa] on the query's mesh."""
        return np.asarray(metrics.oled_objective(np.asarray(vm)[:, None, :], self._weights(q), reading=self.reading))

    def _predict_one(self, kind: str, q) -> Prediction:
        from pcmgn_jax.eval.surrogates import FieldRegression, design_of

        model = self.models[kind]
        t0 = time.perf_counter()
        u = vm = std = obj = None
        note = ""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if kind == "mgn":
                with self._mgn_lock:
                    pu, pv = model.rollout_trajectories([q])
                u, vm = pu[0], pv[0]
                if self._mgn_spread is not None:
                    std = float(self._mgn_spread.predict([q])[1][0])
                    note = "± GP std of the MGN's training residuals"
            elif kind in ("kriging", "mop"):
                surface, fields = model
                if kind == "kriging":
                    mean, sd = surface.predict_trajectories([q], return_std=True)
                    std = float(sd[self.reading][0])
                    note = "± GP posterior std"
                else:
                    mean = surface.predict_trajectories([q])
                    note = f"objective surface ({surface.model.choice[self.reading]}); no fields"
                obj = float(mean[self.reading][0])
                if fields is not None:
                    u, vm = (a[0] for a in fields.predict(design_of(q)[None]))
            elif isinstance(model, FieldRegression):
                u, vm = (a[0] for a in model.predict(design_of(q)[None]))
            else:   # rom, NearestScene: any mesh
                pu, pv = model.predict_trajectories([q])
                u, vm = pu[0], pv[0]
        if u is not None:
            u, vm = np.asarray(u, np.float64), np.asarray(vm, np.float64)
        if obj is None and vm is not None:
            obj = float(metrics.oled_objective_of(q, vm, part=self.part, reading=self.reading))
        return Prediction(kind, obj, std, u, vm, time.perf_counter() - t0, note)

    def predict(self, x, kinds: Sequence[str] | None = None) -> dict[str, Prediction]:
        """{predictor: Prediction} at x (P,) [SI] for ``kinds`` (default :attr:`live`), computed once
        per design (the last :data:`CACHE_DESIGNS` designs are kept)."""
        key = _key(x)
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
        self.latest = _key(x)
        self.predict(x)
        return self.flags(x)

    def predict_rest(self, x) -> bool:
        """The :attr:`deferred` predictors at x when x is still the latest design asked for (work queued
        behind newer slider moves is skipped); True when a prediction was made."""
        todo = [k for k in self.deferred if k not in self._pred.get(_key(x), {})]
        if not todo or (self.latest is not None and _key(x) != self.latest):
            return False
        self.predict(x, todo)
        return True

    def check(self, x) -> Truth:
        """The built-in solver at x (P,) [SI] on the data's preset (seconds on the cpu preset), cached."""
        from pcmgn_jax.sim.output import to_trajectories
        from pcmgn_jax.sim.solver import simulate

        key = _key(x)
        if (known := self._truth.get(key)) is not None:
            return known
        if self.preset is None:
            raise ValueError("the solver check needs solver-generated training data (meta.solver.preset)")
        scene = self.scene_at(x)
        t0 = time.perf_counter()
        with self._solver_lock:
            result = simulate([scene], self.preset)
        (traj,) = to_trajectories(result, [scene], self.preset)
        force = np.concatenate([[0.0], np.asarray(result.force[0])[:, -1]])
        truth = Truth(traj, force, float(metrics.oled_objective_of(traj, part=self.part, reading=self.reading)),
                      time.perf_counter() - t0)
        return self._truth.put(key, truth)

    def truth(self, x) -> Truth | None:
        """The solver check at x if one was run."""
        return self._truth.get(_key(x))

    # ---- the page ------------------------------------------------------------------------------------

    def _text(self, kind: str, p: Prediction | None) -> str:
        if kind in self.skipped:
            return f"n/a: {self.skipped[kind]}"
        if p is None:
            return "computing ..."
        if p.objective_mpa is None:
            return f"n/a: {p.note}"
        std = f" ± {p.std_mpa:.2g}" if p.std_mpa is not None else ""
        return f"{p.objective_mpa:.4g}{std} MPa"

    def rows(self, x) -> list[dict]:
        """The objective table: per predictor its label, value text, [MPa] and std, time [ms], test-split
        error [%] (RUN/eval/metrics.json) and, after a solver check, its error against the truth [%]."""
        preds = self._pred.get(_key(x), {})
        truth = self.truth(x)
        out = []
        for kind in [k for k in PREDICTORS if k in self.models or k in self.skipped]:
            p = preds.get(kind)
            test = self.test_errors.get(kind)
            err = None
            if truth is not None and p is not None and p.objective_mpa is not None:
                err = float(metrics.relative_error_pct(p.objective_mpa, truth.objective_mpa))
            out.append({"name": kind, "label": LABELS[kind] + (" (default)" if kind == self.default else ""),
                        "text": self._text(kind, p), "mpa": None if p is None else p.objective_mpa,
                        "std": None if p is None else p.std_mpa, "ms": None if p is None else 1e3 * p.seconds,
                        "note": "" if p is None else p.note, "error_pct": err,
                        "test": "" if test is None else f"{test[0]:.3g} % ({test[1]:.3g})"})
        if truth is not None:
            out.append({"name": "truth", "label": "the solver (truth)", "text": f"{truth.objective_mpa:.4g} MPa",
                        "mpa": truth.objective_mpa, "std": None, "ms": 1e3 * truth.seconds,
                        "note": f"{self.preset} preset", "error_pct": 0.0, "test": ""})
        return out

    def headline(self, x) -> str:
        """'OLED objective (<reading>) by <predictor>: value ± std MPa', for the default predictor."""
        p = self._pred.get(_key(x), {}).get(self.default)
        what = f"OLED objective ({self.reading.replace('_', ' ')}) by {LABELS[self.default]}"
        if p is None:
            fast = self._pred.get(_key(x), {}).get("kriging")
            meanwhile = f"; kriging meanwhile: {self._text('kriging', fast)}" if fast is not None else ""
            return f"{what}: computing ...{meanwhile}"
        std = f" ± {p.std_mpa:.2g} ({p.note.removeprefix('± ')})" if p.std_mpa is not None else ""
        if p.objective_mpa is None:
            return f"{what}: n/a ({p.note})"
        return f"{what}: {p.objective_mpa:.4g}{std} MPa"

    def choices(self, x) -> list[str]:
        """What the field figures can show at x: predictors with fields, then 'truth' and 'error:<p>' after a check."""
        preds = self._pred.get(_key(x), {})
        have = [k for k in self._field_kinds() if k in preds and preds[k].vm is not None]
        truth = self.truth(x)
        if truth is not None:
            have += ["truth"] + [f"error:{k}" for k in have if preds[k].vm.shape == truth.traj.von_mises.shape]
        return have

    def view(self, x, *, frame: int | None = None, show: str | None = None, scale: str = "log") -> View:
        """The page at x (P,) [SI]: the :attr:`live` predictors are computed if missing (the others by
        :meth:`predict_rest`), then the headline, the table, the flags and the figures of ``show``
        ('truth', 'error:<predictor>' or a predictor with fields; default: the default predictor, or
        the first with fields when it has none yet) at ``frame`` with colour ``scale`` ('log' | 'linear')."""
        from pcmgn_jax.explore import figures

        x = np.asarray(x, float)
        preds = self.predict(x)
        choices = self.choices(x)
        frame = self.start_frame if frame is None else int(np.clip(frame, 0, self.ref.n_frames - 1))
        notes = list(self.notes)
        if show not in choices:
            if show is not None and show != self.default:
                notes.append(f"{show!r} has no fields at this design yet: showing {choices[0] if choices else 'none'}")
            show = choices[0] if choices else None
        q, truth = self.query(x), self.truth(x)
        figs = {"box": figures.box_figure(self.params, x, self.scenes.x, self.out_of_box(x),
                                          band=None if self.family else _band(len(x)))}
        names = list(self.scene0.part_names)
        if show is None:
            empty = figures.message_figure("no predictor with fields at this design")
            figs.update(field=empty, oled=empty, history=empty)
        else:
            if show == "truth" or show.startswith("error:"):
                mesh, u = truth.traj, truth.traj.displacement
                vm = truth.traj.von_mises
                label = f"the solver ({self.preset} preset)"
                if show.startswith("error:"):
                    kind = show.split(":", 1)[1]
                    vm = np.abs(preds[kind].vm - truth.traj.von_mises)
                    label = f"|{LABELS[kind]} − solver|"
            else:
                mesh, u, vm, label = q, preds[show].u, preds[show].vm, LABELS[show]
            t_us = 1e6 * float(self.ref.times[frame])
            pts = np.asarray(mesh.points) + u[frame]
            figs["field"] = figures.field_figure(pts, mesh.cells, mesh.cell_part, vm[frame], names,
                                                 title=f"von Mises: {label}, frame {frame} (t = {t_us:.0f} µs), "
                                                       f"deformed section at true scale", scale=scale,
                                                 vmax_pa=float(np.nanmax(vm)))
            figs["oled"] = figures.oled_figure(pts, mesh.cells, mesh.cell_part, vm[frame], self.part,
                                               x_max=metrics.OBJECTIVE_X_MAX, vmax_pa=float(
                                                   np.nanmax(vm[:, np.asarray(mesh.node_part) == self.part])),
                                               title=f"OLED layer: {label}, frame {frame} (linear scale)")
            curves, ball = {}, {}
            for k in self._field_kinds():
                if k in preds and preds[k].vm is not None:
                    curves[LABELS[k]] = self.objective_history(q, preds[k].vm)
                    ball[LABELS[k]] = _ball_um(q, preds[k].u)
            if truth is not None:
                curves["solver"] = self.objective_history(truth.traj, truth.traj.von_mises)
                ball["solver"] = _ball_um(truth.traj, truth.traj.displacement)
            figs["history"] = figures.history_figure(
                1e6 * np.asarray(self.ref.times), curves, ball, None if truth is None else truth.force, frame,
                objective={LABELS[k]: p.objective_mpa for k, p in preds.items() if p.objective_mpa is not None})
        return View(self.headline(x), self.rows(x), self.flags(x), notes, show or "", figs)


def _band(dim: int):
    """The optimiser's sum band (low, high) [m] of a design of ``dim`` design layers (opt/problem.py)."""
    from pcmgn_jax.opt.problem import DesignBox
    b = DesignBox(dim=dim)
    return b.sum_low, b.sum_high


def _ball_um(traj, u) -> np.ndarray:
    """(T,) the ball's mean vertical displacement [µm] (the ROI's ball nodes) of u (T, N, 2) [m]."""
    ball = np.asarray(traj.node_part) == 0
    return 1e6 * np.asarray(u)[:, ball, 1].mean(axis=1)
