"""The solver in the loop: fit a surrogate, let an acquisition pick the next design, run the solver, repeat.

    problem = Problem(names=("OCA1", "OCA2"), low=(50e-6,) * 2, high=(150e-6,) * 2, oracle=SolverOracle(...))
    log = run_loop(problem, LoopConfig(surrogate="kriging", acquisition="ei", budget=16), "RUN/active/x.json")
    log["rounds"][-1]["best"]              # {'design_um', 'mpa'}: the best solver value seen, its design

A :class:`Problem` is a design box (bounds [SI] per design variable and the paper's band on the sum of
some of them, :class:`~pcmgn_jax.opt.problem.DesignBox`), a set of drop cases (extra scene parameters; the
objective is their mean) and an oracle that answers a design with one solver value per case [MPa].
Round 0 runs ``n_init`` seeded Latin-hypercube designs; every later round fits the surrogate on every
(parameter row, solver value) pair so far (plus the problem's prior data), scores a fixed candidate set
(a regular grid for two variables, a seeded LHS otherwise; feasible only) with the acquisition
(:mod:`pcmgn_jax.opt.acquisition`) and runs the ``batch`` best that are not yet run. The log is written
atomically after every round; a rerun with the same config replays it and goes on (fits are deterministic,
so the resumed rounds are those an unbroken run makes; the oracle's cache keeps solver runs of a round cut
short). A failing solver run raises :class:`ActiveLearningError` naming the round and design; the rounds
before it stay in the log.

Surrogates over the parameter rows (design variables, then the case's parameters), each giving a mean
and a spread per row [MPa]:

- ``kriging``  the GP response surface (:class:`~pcmgn_jax.surrogates.surface_fit.Kriging`), its posterior std
- ``auto``     MOP's choice by leave-one-out CoP (:class:`~pcmgn_jax.surrogates.surface_fit.MOP`) for the mean,
               the kriging std for the spread; the CoP table goes to the round's log
- ``mgn``      a trained model's prediction (``base``) plus a GP on the solver's residuals from it: the
               model corrected where the solver has answered, its spread the residual GP's std

The case mean's spread is the mean of the cases' stds (the bound for fully correlated errors).
"""
from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from pcmgn_jax.atomic import atomic_write_json
from pcmgn_jax.opt import acquisition as acq
from pcmgn_jax.opt.problem import DesignBox
from pcmgn_jax.surrogates.kinds import choices
from pcmgn_jax.surrogates.surface_fit import fit_gp, fit_surface

# the loop's surrogates: the kinds with ``active`` (pcmgn_jax/surrogates/kinds.py), fitted here over parameter
# rows (the solver's answers), and ``auto`` (MOP's mean, kriging's spread)
ACTIVE_SURROGATES = choices("active")
ACTIVE_FORMAT = "pcmgn_jax.active"
GRID_N = 41          # candidate grid per axis for two design variables (2.5 µm steps over 50-150 µm)
N_CANDIDATES = 4000  # seeded LHS candidates for more variables
CANDIDATE_SEED = 12345


class ActiveLearningError(RuntimeError):
    """A round of the loop failed (the solver, or a config that does not match the log)."""


@dataclass(frozen=True)
class LoopConfig:
    surrogate: str = "kriging"   # kriging | auto | mgn (module docstring)
    acquisition: str = "ei"      # ei | lcb | mean (pcmgn_jax.opt.acquisition)
    budget: int = 16             # solver runs in the loop (designs x cases), prior data not counted
    n_init: int = 4              # designs of round 0 (seeded LHS)
    batch: int = 1               # designs per later round
    seed: int = 0                # the LHS seed
    kappa: float = acq.KAPPA

    def check(self, n_cases: int) -> None:
        if self.surrogate not in ACTIVE_SURROGATES:
            raise ValueError(f"surrogate must be one of {ACTIVE_SURROGATES}, got {self.surrogate!r}")
        if self.acquisition not in acq.ACQUISITIONS:
            raise ValueError(f"acquisition must be one of {acq.ACQUISITIONS}, got {self.acquisition!r}")
        if self.n_init < 1 or self.batch < 1:
            raise ValueError(f"n_init and batch must be >= 1, got {self.n_init}, {self.batch}")
        if self.budget < self.n_init * n_cases:
            raise ValueError(f"budget {self.budget} is below round 0's {self.n_init} designs x {n_cases} cases")


@dataclass
class Problem:
    """A design problem (module docstring). ``names``: the design variables (scene parameter names);
    ``low`` / ``high`` their bounds [SI]; ``band``: the sum band on the variables ``band_vars`` (default
    all of them); ``cases``: extra parameters per drop case ({} once: the scene as it is); ``oracle``:
    design (D,) [SI] -> (C,) solver values [MPa]; ``row_names``: the surrogate's parameter order (default
    names + the cases' keys); ``prior``: (rows (n, P), values (n,)) known before the loop; ``holdout``:
    (rows, values) the surrogate is scored on each round; ``reference``: {'design_um', 'mpa'} the best
    design known, for the gap."""

    names: tuple[str, ...]
    low: tuple[float, ...]
    high: tuple[float, ...]
    oracle: Callable[[np.ndarray], np.ndarray]
    band: DesignBox | None = field(default_factory=DesignBox)
    band_vars: tuple[str, ...] | None = None
    cases: tuple[dict, ...] = ({},)
    row_names: tuple[str, ...] | None = None
    prior: tuple[np.ndarray, np.ndarray] | None = None
    holdout: tuple[np.ndarray, np.ndarray] | None = None
    reference: dict | None = None

    def __post_init__(self):
        self.names, self.cases = tuple(self.names), tuple(dict(c) for c in self.cases)
        self.low, self.high = np.asarray(self.low, float), np.asarray(self.high, float)
        if self.low.shape != (len(self.names),) or self.high.shape != self.low.shape or np.any(self.low >= self.high):
            raise ValueError(f"problem: need low < high for each of {self.names}, got {self.low}, {self.high}")
        keys = sorted({k for c in self.cases for k in c})
        if any(set(c) != set(keys) for c in self.cases):
            raise ValueError(f"problem: every drop case must set the same parameters {keys}, got {self.cases}")
        self.row_names = tuple(self.row_names or (*self.names, *keys))
        missing = [n for n in (*self.names, *keys) if n not in self.row_names]
        if missing:
            raise ValueError(f"problem: row_names {self.row_names} lack {missing}")
        bv = self.band_vars or self.names
        self._band_idx = [self.names.index(n) for n in bv] if self.band is not None else []

    # ---- the design space ---------------------------------------------------------------------------
    def feasible(self, designs) -> np.ndarray:
        d = np.atleast_2d(np.asarray(designs, float))
        tol = 1e-12
        ok = np.all((d >= self.low - tol) & (d <= self.high + tol), axis=1)
        if self._band_idx:
            ok &= self.band.violation(d[:, self._band_idx]) <= tol
        return ok

    def project(self, designs) -> np.ndarray:
        d = np.clip(np.atleast_2d(np.asarray(designs, float)), self.low, self.high)
        if self._band_idx:
            d[:, self._band_idx] = self.band.project(d[:, self._band_idx])
        return d

    def lhs(self, n: int, seed: int) -> np.ndarray:
        """(n, D) seeded Latin-hypercube designs [SI], projected onto the feasible set."""
        from scipy.stats import qmc
        z = qmc.LatinHypercube(d=len(self.names), rng=np.random.default_rng(seed)).random(n)
        return self.project(self.low + z * (self.high - self.low))

    def candidates(self) -> np.ndarray:
        """(Q, D) the fixed feasible candidate set [SI] (module docstring)."""
        if len(self.names) == 2:
            g = [np.linspace(a, b, GRID_N) for a, b in zip(self.low, self.high)]
            d = np.stack(np.meshgrid(*g, indexing="xy"), axis=-1).reshape(-1, 2)
        else:
            from scipy.stats import qmc
            z = qmc.LatinHypercube(d=len(self.names), rng=np.random.default_rng(CANDIDATE_SEED)).random(N_CANDIDATES)
            d = self.low + z * (self.high - self.low)
        return d[self.feasible(d)]

    def rows(self, designs) -> np.ndarray:
        """(B * C, P) parameter rows [SI] of designs (B, D), design-major, in ``row_names`` order."""
        out = []
        for d in np.atleast_2d(np.asarray(designs, float)):
            for c in self.cases:
                vals = {**dict(zip(self.names, d)), **c}
                out.append([vals[n] for n in self.row_names])
        return np.asarray(out, float).reshape(-1, len(self.row_names))


# ---- surrogates over parameter rows --------------------------------------------------------------------
def fit_surrogate(kind: str, rows, values, names: Sequence[str], base: Callable | None = None):
    """(predict(rows) -> (mean (Q,), std (Q,)) [MPa], info dict) of surrogate ``kind`` fitted on
    rows (n, P) [SI] and solver values (n,) [MPa] (module docstring); ``base``: rows -> (n,) for ``mgn``."""
    X, y = np.asarray(rows, float), np.asarray(values, float)
    info: dict = {"n_samples": len(y)}
    if kind == "mgn":
        if base is None:
            raise ValueError("surrogate 'mgn': needs a trained model's prediction (base)")
        b = np.asarray(base(X), float)
        k = fit_gp(X, {"f": y - b}, names=names, checking=False)
        info["residual_rms_mpa"] = float(np.sqrt(np.mean((y - b) ** 2)))

        def predict(q):
            m, s = k.predict(q, return_std=True)
            return np.asarray(base(q), float) + m["f"], s["f"]
        return predict, info
    k = fit_gp(X, {"f": y}, names=names, checking=False)
    if kind == "kriging":
        def predict(q):
            m, s = k.predict(q, return_std=True)
            return m["f"], s["f"]
        return predict, info
    if kind != "auto":
        raise ValueError(f"surrogate must be one of {ACTIVE_SURROGATES}, got {kind!r}")
    mop = fit_surface("mop", X, {"f": y}, names=names, checking=False)
    info["mop"] = mop.report()["f"]

    def predict(q):
        return mop.predict(q)["f"], k.predict(q, return_std=True)[1]["f"]
    return predict, info


def _case_mean(problem: Problem, predict, designs) -> tuple[np.ndarray, np.ndarray]:
    m, s = predict(problem.rows(designs))
    C = len(problem.cases)
    return np.asarray(m).reshape(-1, C).mean(1), np.asarray(s).reshape(-1, C).mean(1)


# ---- the loop -----------------------------------------------------------------------------------------
def _load(path: Path, header: dict) -> list[dict]:
    if not path.exists():
        return []
    try:
        got = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ActiveLearningError(f"{path}: unreadable active-learning log ({e}); move it away to start afresh") from e
    if got.get("format") != ACTIVE_FORMAT:
        raise ActiveLearningError(f"{path}: not an active-learning log (format {got.get('format')!r})")
    # a larger budget goes on where the log stopped; anything else must match
    diff = {k: (got["config"].get(k), v) for k, v in header["config"].items()
            if k != "budget" and got["config"].get(k) != v}
    if diff:
        raise ActiveLearningError(f"{path}: the log was made with another config {diff} (saved, given); "
                                  "use another --out or remove the log")
    return got["rounds"]


def _um(d) -> list:
    """Designs [m] as µm lists, rounded to 0.1 nm (no float noise in the log)."""
    return np.round(np.asarray(d, float) * 1e6, 4).tolist()


def _key(d) -> tuple:
    return tuple(np.round(np.asarray(d, float) * 1e9).astype(np.int64).tolist())   # nm


def _header(problem: Problem, cfg: LoopConfig, meta) -> dict:
    return {"format": ACTIVE_FORMAT, "format_version": 1, "config": dataclasses.asdict(cfg),
            "problem": {"names": list(problem.names), "low": problem.low.tolist(), "high": problem.high.tolist(),
                        "cases": list(problem.cases), "row_names": list(problem.row_names),
                        "n_prior": 0 if problem.prior is None else len(problem.prior[1]),
                        "reference": problem.reference},
            "meta": dict(meta or {})}


def _propose(problem: Problem, cfg: LoopConfig, cands, designs, values, n_runs: int, base):
    """(picks (n, D) [SI], proposal record, holdout error record) of a round after round 0."""
    X0, y0 = (np.zeros((0, len(problem.row_names))), np.zeros(0)) if problem.prior is None else \
        (np.asarray(problem.prior[0], float), np.asarray(problem.prior[1], float))
    X = np.concatenate([X0, problem.rows(np.stack(designs))])
    y = np.concatenate([y0, np.concatenate(values)])
    predict, info = fit_surrogate(cfg.surrogate, X, y, problem.row_names, base)
    mean, std = _case_mean(problem, predict, cands)
    best = min(float(v.mean()) for v in values)
    done = {_key(d) for d in designs}
    exclude = np.array([_key(d) in done for d in cands])
    idx = []
    for _ in range(min(cfg.batch, (cfg.budget - n_runs) // len(problem.cases))):
        i = acq.propose(mean, std, best, cfg.acquisition, exclude=exclude, kappa=cfg.kappa)
        idx.append(i)
        exclude = exclude | _near(cands, cands[i], problem)
    sc = acq.scores(mean, std, best, cfg.acquisition, kappa=cfg.kappa)
    i0 = int(np.argmin(mean))
    proposal = {"kind": cfg.acquisition, "surrogate": cfg.surrogate, "fit": info,
                "predicted_mpa": mean[idx].tolist(), "predicted_std_mpa": std[idx].tolist(), "score": sc[idx].tolist(),
                "surrogate_optimum": {"design_um": _um(cands[i0]), "mpa": float(mean[i0]), "std_mpa": float(std[i0])}}
    holdout = None
    if problem.holdout is not None:
        hm, _ = predict(np.asarray(problem.holdout[0], float))
        ht = np.asarray(problem.holdout[1], float)
        err = 100 * np.abs(hm - ht) / np.maximum(np.abs(ht), 1e-12)
        holdout = {"mae_pct": float(err.mean()), "max_pct": float(err.max()), "n": len(ht)}
    return cands[idx], proposal, holdout


def _solve(problem: Problem, picks, k: int, path: Path, bar) -> list[np.ndarray]:
    """(C,) solver values [MPa] per pick; a failure is an ActiveLearningError naming round k and the designs."""
    C = len(problem.cases)
    out = []
    many = getattr(problem.oracle, "many", None)
    for group in ([picks] if many is not None else [p[None] for p in picks]):
        try:
            got = many(group) if many is not None else [problem.oracle(group[0])]
        except Exception as e:   # noqa: BLE001 - any solver failure is named with its round and designs
            raise ActiveLearningError(
                f"round {k}: the solver failed at design {'; '.join(map(str, _um(group)))} µm ({type(e).__name__}: "
                f"{e}); the {k} finished rounds are kept in {path}") from e
        out += [np.asarray(v, float).reshape(C) for v in got]
        if bar is not None:
            bar.update(C * len(group))
    return out


def run_loop(problem: Problem, cfg: LoopConfig, log_path: str | Path, *, base: Callable | None = None,
             meta: Mapping | None = None, progress: bool = True) -> dict:
    """Run (or resume) the loop of ``cfg`` on ``problem`` up to its budget, logging to ``log_path`` (JSON,
    atomic per round); returns the log. ``base``: the model's prediction for ``mgn``; ``meta``: recorded."""
    C = len(problem.cases)
    cfg.check(C)
    path = Path(log_path)
    header = _header(problem, cfg, meta)
    rounds = _load(path, header)
    path.parent.mkdir(parents=True, exist_ok=True)
    cands = problem.candidates()
    designs = [np.asarray(d, float) * 1e-6 for r in rounds for d in r["designs_um"]]
    values = [np.asarray(v, float) for r in rounds for v in r["case_values_mpa"]]
    n_runs = len(designs) * C
    if progress and rounds:
        print(f"{path}: resuming after round {rounds[-1]['round']} ({n_runs} solver runs done)")
    bar = None
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=cfg.budget, initial=n_runs, desc=f"active {cfg.surrogate}-{cfg.acquisition}", unit="run")
    while n_runs + C <= cfg.budget:
        t0 = time.perf_counter()
        k = len(rounds)
        if k == 0:
            picks, proposal, holdout = problem.lhs(cfg.n_init, cfg.seed), {"kind": "lhs", "seed": cfg.seed}, None
        else:
            picks, proposal, holdout = _propose(problem, cfg, cands, designs, values, n_runs, base)
        # the designs as the log holds them (0.1 nm): a resumed run sees the same numbers
        picks = np.asarray(_um(picks), float).reshape(-1, len(problem.names)) * 1e-6
        new_vals = _solve(problem, picks, k, path, bar)
        designs += list(picks)
        values += new_vals
        n_runs += len(picks) * C
        objs = [float(v.mean()) for v in values]
        j = int(np.argmin(objs))
        rec = {"round": k, "designs_um": _um(picks),
               "case_values_mpa": [v.tolist() for v in new_vals], "objective_mpa": [float(v.mean()) for v in new_vals],
               "proposal": proposal, "holdout_error": holdout, "solver_runs": n_runs,
               "best": {"design_um": _um(designs[j]), "mpa": objs[j], "case_values_mpa": values[j].tolist()},
               "seconds": time.perf_counter() - t0}
        if problem.reference is not None:
            rec["best"]["gap_pct"] = 100 * (objs[j] - problem.reference["mpa"]) / problem.reference["mpa"]
        rounds.append(rec)
        atomic_write_json(path, {**header, "rounds": rounds})
    if bar is not None:
        bar.close()
    out = {**header, "rounds": rounds}
    atomic_write_json(path, out)
    return out


def _near(cands, d, problem: Problem, frac: float = 0.05) -> np.ndarray:
    """(Q,) candidates within ``frac`` of the box (scaled, max-norm) of design d: not picked twice in a batch."""
    return np.max(np.abs(cands - d) / (problem.high - problem.low), axis=1) < frac


def best_at(log: dict, budget: int) -> dict | None:
    """The best solver value of the log's rounds that fit in ``budget`` solver runs ({design_um, mpa,
    solver_runs}), or None when round 0 alone exceeds it."""
    fit = [r for r in log["rounds"] if r["solver_runs"] <= budget]
    if not fit:
        return None
    return {**fit[-1]["best"], "solver_runs": fit[-1]["solver_runs"]}


class SolverOracle:
    """Design (D,) [SI] -> (C,) the built-in solver's ``reading`` [MPa] per drop case, every run cached as
    JSON under ``cache_dir`` (:func:`pcmgn_jax.opt.check.solver_objectives`). ``scene``: the base
    :class:`~pcmgn_jax.scene.Scene` whose design layers are the design variables; ``cases``: the drop
    cases' scene parameters (:func:`pcmgn_jax.scene.with_parameters`); ``preset``: the mesh preset."""

    def __init__(self, scene, preset: str, *, reading: str = "area_mean", cases: Sequence[dict] = ({},),
                 cache_dir: str | Path | None = None):
        from pcmgn_jax.scene import with_parameters
        self.preset, self.reading, self.cache_dir = preset, reading, cache_dir
        self.scenes = [(with_parameters(scene, c) if c else scene, _case_label(preset, c)) for c in cases]
        self.seconds = 0.0

    def __call__(self, design) -> np.ndarray:
        return self.many(np.asarray(design, float)[None])[0]

    def many(self, designs) -> np.ndarray:
        """(B, C) [MPa] of designs (B, D) [SI]: per case one batched solver call for the uncached designs."""
        from pcmgn_jax.opt.check import solver_objectives_many
        cols = []
        for scene, label in self.scenes:
            got = solver_objectives_many(scene, designs, self.preset, self.cache_dir, label=label)
            self.seconds += sum(0.0 if g["cached"] else g["solver_seconds"] for g in got)
            cols.append([g[self.reading] for g in got])
        return np.asarray(cols).T


def _case_label(preset: str, case: Mapping) -> str:
    return preset + "".join(f"_{k}={v:.6g}" for k, v in sorted(case.items()))
