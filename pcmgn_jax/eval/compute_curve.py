"""The MGN's compute curve: its test errors against training steps, a power-law fit with its uncertainty, and the
training compute at which the fit meets a baseline.

    points = [curve_point(run) for run in runs]          # one per trained run (RUN/config.json, RUN/eval/...)
    points += [kept_point("16000:1:results/.../metrics.json")]   # a run whose folder is gone, its evaluation kept
    fits = {m: fit_power_law(points, m) for m in CURVE_METRICS}  # error = a * steps ** -b, least squares in log-log
    s = crossing(fits[m], baseline_value)                   # steps at which the fit meets the baseline

The fit is ordinary least squares of ln(error) on ln(steps) over every run (each seed its own point), its parameter
covariance the residual variance times (XᵀX)⁻¹ (n − 2 degrees of freedom, so three points give a wide band, as they
should). The uncertainty of a crossing is the 16th–84th percentile of the crossings of fits drawn from that
covariance; for the objective also a bootstrap over the test designs (the runs share one test split, so a resample
draws the same designs for every run). A fit whose error does not fall (b ≤ 0) never meets a lower baseline: its
crossing is ``inf``. Errors are the evaluation's own figures (``RUN/eval/metrics.json``, :mod:`pcmgn_jax.eval.evaluate`;
the objective by :func:`pcmgn_jax.metrics.relative_error_pct`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pcmgn_jax import metrics as M
from pcmgn_jax.errors import SettingError

# (metrics.json key, label); the objective is the area-mean reading the task table scores
CURVE_METRICS = (("oled_objective_area_rel_error_pct_mean", "objective error, area mean [%]"),
                 ("position_mae_um", "position MAE [µm]"), ("stress_mae_mpa", "stress MAE [MPa]"))
OBJECTIVE = CURVE_METRICS[0][0]


@dataclass(frozen=True)
class CurvePoint:
    """One trained run's test errors. ``steps``: its training length (config ``num_steps``); ``steps_per_s``: the
    median logged training rate (validation excluded); ``objective_true`` / ``objective_pred`` [MPa] per test design."""
    run: str
    steps: int
    seed: int
    steps_per_s: float
    errors: dict
    objective_true: np.ndarray
    objective_pred: np.ndarray
    baselines: dict


def _read_json(path: Path, what: str) -> dict:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no {what} (train and evaluate the run first)")
    return json.loads(path.read_text())


def curve_point(run: str | Path) -> CurvePoint:
    """The point of one trained and evaluated run (``RUN/config.json``, ``RUN/metrics.jsonl``,
    ``RUN/eval/metrics.json``)."""
    run = Path(run)
    cfg = _read_json(run / "config.json", "config.json")
    log = run / "metrics.jsonl"
    rates = [r["steps_per_s"] for r in map(json.loads, log.read_text().splitlines()[1:] if log.is_file() else [])
             if np.isfinite(r.get("steps_per_s", np.nan))]
    steps = int(cfg.get("num_steps") or 0)
    if steps <= 0:
        raise ValueError(f"{run / 'config.json'}: num_steps {steps}: the curve needs runs of a fixed step count")
    return _point(run, run / "eval" / "metrics.json", steps, int(cfg.get("seed", 0)),
                  float(np.median(rates)) if rates else float("nan"))


def kept_point(spec: str) -> CurvePoint:
    """The point of a run whose folder is gone but whose evaluation was kept: ``STEPS:SEED:PATH`` with PATH its
    ``eval/metrics.json`` (e.g. one committed under ``results/``). Its training rate is unknown (nan: the hours
    use the other runs' rate)."""
    parts = spec.split(":", 2)
    if len(parts) != 3 or not parts[0].strip().isdigit() or not parts[1].strip().isdigit() or int(parts[0]) <= 0:
        raise SettingError("kept", f"{spec!r}: expected STEPS:SEED:PATH (e.g. 16000:0:results/.../metrics.json)")
    path = Path(parts[2].strip())
    return _point(path, path, int(parts[0]), int(parts[1]), float("nan"))


def _point(run: Path, metrics_path: Path, steps: int, seed: int, steps_per_s: float) -> CurvePoint:
    m = _read_json(metrics_path, "evaluation metrics")
    missing = [k for k in (*(k for k, _ in CURVE_METRICS), "oled_objective_area_true_mpa",
                           "oled_objective_area_pred_mpa") if k not in m]
    if missing:
        raise ValueError(f"{metrics_path}: no {', '.join(missing)} (not an experiments.evaluate metrics.json)")
    return CurvePoint(run=str(run), steps=steps, seed=seed, steps_per_s=steps_per_s,
                      errors={k: float(m[k]) for k, _ in CURVE_METRICS},
                      objective_true=np.asarray(m["oled_objective_area_true_mpa"], np.float64),
                      objective_pred=np.asarray(m["oled_objective_area_pred_mpa"], np.float64),
                      baselines={k: {key: v[key] for key, _ in CURVE_METRICS if key in v}
                                 for k, v in m.get("baselines", {}).items() if "not_applicable" not in v})


@dataclass(frozen=True)
class PowerLaw:
    """error = a * steps ** -b; ``cov``: covariance of (ln a, b); ``n`` points."""
    ln_a: float
    b: float
    cov: np.ndarray
    n: int


def _ols(steps, errors) -> PowerLaw:
    x = np.log(np.asarray(steps, np.float64))
    y = np.log(np.maximum(np.asarray(errors, np.float64), 1e-300))
    X = np.stack([np.ones_like(x), -x], axis=1)
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    n = len(x)
    if n < 3 or np.ptp(x) == 0:
        raise ValueError(f"a power-law fit with an uncertainty needs >= 3 runs over >= 2 step counts, got {n} "
                         f"run(s) at steps {sorted(set(np.exp(x).round().astype(int)))}")
    dof = n - 2
    sigma2 = float(np.sum((y - X @ beta) ** 2) / dof)
    return PowerLaw(ln_a=float(beta[0]), b=float(beta[1]), cov=sigma2 * np.linalg.inv(X.T @ X), n=n)


def fit_power_law(points: list[CurvePoint], metric: str) -> PowerLaw:
    """Least-squares power law of ``metric`` against training steps over ``points``."""
    return _ols([p.steps for p in points], [p.errors[metric] for p in points])


def crossing(ln_a, b, target: float):
    """Steps at which a * s ** -b = target (``inf`` where b <= 0 and the target lies below the fit)."""
    ln_a, b = np.asarray(ln_a, np.float64), np.asarray(b, np.float64)
    safe_b = np.where(b > 0, b, 1.0)
    s = np.exp(np.minimum((ln_a - np.log(target)) / safe_b, 700.0))   # beyond e^700 steps is never, in effect
    return np.where(b > 0, s, np.where(np.exp(ln_a) <= target, 1.0, np.inf))


def _percentiles(s) -> dict:
    """16th / 50th / 84th percentiles of crossings, some of them ``inf`` (read off the sorted draws, no
    interpolation between an infinite and a finite one), and the share that never cross."""
    q = {f"p{p}": float(np.quantile(s, p / 100, method="inverted_cdf")) for p in (16, 50, 84)}
    return dict(**q, share_never=float(np.mean(~np.isfinite(s))))


def crossing_interval(fit: PowerLaw, target: float, *, draws: int = 20000, seed: int = 0) -> dict:
    """The fit's crossing of ``target`` and its 16th / 50th / 84th percentiles over fits drawn from the fit's
    parameter covariance."""
    rng = np.random.default_rng(seed)
    lab = rng.multivariate_normal([fit.ln_a, fit.b], fit.cov, size=draws)
    s = crossing(lab[:, 0], lab[:, 1], target)
    return dict(steps=float(crossing(fit.ln_a, fit.b, target)), **_percentiles(s))


def objective_bootstrap(points: list[CurvePoint], *, draws: int = 2000, seed: int = 0) -> tuple[np.ndarray, ...]:
    """(ln a, b) of the objective's fit over ``draws`` bootstrap resamples of the shared test designs."""
    n = {p.objective_true.size for p in points}
    if len(n) != 1:
        raise ValueError(f"the runs were evaluated on test splits of different sizes {sorted(n)}: one split needed")
    rel = np.stack([M.relative_error_pct(p.objective_pred, p.objective_true) for p in points])   # runs x designs
    idx = np.random.default_rng(seed).integers(0, rel.shape[1], size=(draws, rel.shape[1]))
    steps = [p.steps for p in points]
    fits = [_ols(steps, rel[:, i].mean(axis=1)) for i in idx]
    return np.array([f.ln_a for f in fits]), np.array([f.b for f in fits])


def bootstrap_crossing(ln_a: np.ndarray, b: np.ndarray, target: float) -> dict:
    """Crossing of ``target`` over the bootstrap fits of :func:`objective_bootstrap`, and the spread of b."""
    return dict(**_percentiles(crossing(ln_a, b, target)), b_p16=float(np.percentile(b, 16)),
                b_p84=float(np.percentile(b, 84)))


def summary(points: list[CurvePoint], *, gpu_steps_per_s: float | None = None) -> dict:
    """Per metric: the fit (a, b and their standard errors) and, per baseline the evaluation scored (each one
    that reports the metric), the crossing in steps (with its interval) and in hours at this machine's measured
    rate (and at ``gpu_steps_per_s``, a measured GPU rate, when given). The baselines are those of the largest
    run that scored them (they do not depend on the MGN)."""
    if not points:
        raise ValueError("no runs given")
    points = sorted(points, key=lambda p: (p.steps, p.seed))
    rates = [p.steps_per_s for p in points if np.isfinite(p.steps_per_s)]
    rate = float(np.median(rates)) if rates else float("nan")
    scored = [p for p in points if p.baselines]
    if not scored:
        raise ValueError("no run's evaluation scored the baselines (evaluate one run without --no_baselines)")
    base = scored[-1].baselines
    out = dict(runs=[dict(run=p.run, steps=p.steps, seed=p.seed, steps_per_s=p.steps_per_s, **p.errors)
                     for p in points], cpu_steps_per_s=rate, gpu_steps_per_s=gpu_steps_per_s, metrics={})
    boot = objective_bootstrap(points)   # resampled once, read at every baseline's error
    for key, label in CURVE_METRICS:
        fit = fit_power_law(points, key)
        se = np.sqrt(np.diag(fit.cov))
        entry = dict(label=label, a=float(np.exp(fit.ln_a)), b=fit.b, b_se=float(se[1]), ln_a_se=float(se[0]),
                     baselines={}, n=fit.n)
        for name, vals in base.items():
            if key not in vals:
                continue
            c = crossing_interval(fit, vals[key])
            c["value"] = vals[key]
            c["cpu_hours"] = c["steps"] / rate / 3600.0
            if gpu_steps_per_s:
                c["gpu_hours"] = c["steps"] / gpu_steps_per_s / 3600.0
            if key == OBJECTIVE:
                c["bootstrap"] = bootstrap_crossing(*boot, vals[key])
            entry["baselines"][name] = c
        out["metrics"][key] = entry
    return out


def _steps(s: float) -> str:
    return "never (the fit does not fall)" if not np.isfinite(s) else f"{s:.3g}"


def _exponent(b: float) -> str:
    """−b as an exponent: a falling fit reads steps^−0.19, a rising one steps^+0.06."""
    return f"−{b:.3f}" if b >= 0 else f"+{-b:.3f}"


def _rate(r: float) -> str:
    return f"{r:.2f}" if np.isfinite(r) else "— (kept evaluation)"


def _hours(h: float) -> str:
    return "—" if not np.isfinite(h) else (f"{h:.3g} h" if h < 24 * 365 else f"{h / 24 / 365:.3g} years")


def markdown_lines(s: dict) -> list[str]:
    """The page's tables: the runs, then per metric the fit and the crossings."""
    from pcmgn_jax import markdown
    lines = markdown.table(["run", "steps", "seed", "steps/s (CPU)", *(label for _, label in CURVE_METRICS)],
                           [[Path(r["run"]).name, r["steps"], r["seed"], _rate(r["steps_per_s"]),
                             *(f"{r[k]:.4g}" for k, _ in CURVE_METRICS)] for r in s["runs"]])
    for key, e in s["metrics"].items():
        lines += ["", f"**{e['label']}**: error = {e['a']:.4g} × steps^{_exponent(e['b'])} (b ± {e['b_se']:.3f}, "
                  f"{e['n']} runs)", ""]
        head = ["baseline", "its error", "fit meets it at [steps]", "16–84 % [steps]", "CPU time"]
        if s.get("gpu_steps_per_s"):
            head.append("GPU time")
        rows = []
        for name, c in sorted(e["baselines"].items(), key=lambda kv: kv[1]["value"]):
            band = f"{_steps(c['p16'])} – {_steps(c['p84'])}"
            if "bootstrap" in c:
                band += f" (designs resampled: {_steps(c['bootstrap']['p16'])} – {_steps(c['bootstrap']['p84'])})"
            row = [name, f"{c['value']:.4g}", _steps(c["steps"]), band, _hours(c["cpu_hours"])]
            if s.get("gpu_steps_per_s"):
                row.append(_hours(c["gpu_hours"]))
            rows.append(row)
        lines += markdown.table(head, rows)
    return lines


def plot(path, s: dict) -> None:
    """Error against training steps per metric (log-log): the runs, the fit extended to 1e6 steps, the
    baselines as flat lines."""
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(s["metrics"]), figsize=(5 * len(s["metrics"]), 3.8))
    grid = np.geomspace(min(r["steps"] for r in s["runs"]) / 2, 1e6, 100)
    for ax, (key, e) in zip(np.atleast_1d(axes), s["metrics"].items()):
        for seed in sorted({r["seed"] for r in s["runs"]}):
            rs = [r for r in s["runs"] if r["seed"] == seed]
            ax.plot([r["steps"] for r in rs], [r[key] for r in rs], "o", label=f"MGN seed {seed}")
        ax.plot(grid, e["a"] * grid ** -e["b"], "k--", lw=1, label=f"fit, b = {e['b']:.2f}")
        for i, (name, c) in enumerate(sorted(e["baselines"].items())):
            ax.axhline(c["value"], lw=1, alpha=0.7, color=f"C{2 + i % 8}", label=name)
        ax.set(xscale="log", yscale="log", xlabel="training steps", ylabel=e["label"])
        ax.grid(True, which="both", alpha=0.3)
    np.atleast_1d(axes)[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
