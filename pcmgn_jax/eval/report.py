"""One self-contained HTML report of a run: ``python -m experiments.report --workdir RUN`` -> RUN/report.html.

    run = load_run("runs/cpu")                        # the files, as dicts and PNG bytes
    html = render(run, optimize_table=lines)          # a str: inline CSS, PNGs as data URIs, no link out
    write_report("runs/cpu", optimize_table=lines)    # RUN/report.html, atomically

What it reads (every file but the first is optional; a missing one is said on the page):

- ``RUN/eval[/NAME]/metrics.json`` (:mod:`pcmgn_jax.eval.evaluate`): the model's and the baselines' summary
  metrics, the per-part errors, the OLED objective per test design; its PNGs, embedded as base64 data URIs;
  the other evaluations under ``RUN/eval/*/metrics.json`` as tables
- ``RUN/config.json`` (the run's :class:`pcmgn_jax.config.TrainConfig`), ``RUN/metrics.jsonl`` (last line)
- provenance: ``RUN/data.json`` (the trajectories the run trained and validated on, with hashes) and the
  dataset's ``manifest.json`` (preset, scene, design origin, test designs) when the dataset is still there
- design optimisation: ``RUN/opt*/*.json`` results of ``experiments.optimize`` (:func:`optimize_results`)
  with their objective maps; the Table-8 lines themselves come from :func:`pcmgn_jax.opt.table.rows`,
  passed in by the entry point (evaluation never imports the optimiser)

Every string from a file is HTML-escaped. Units as in the metrics: µm, MPa, s.
"""
from __future__ import annotations

import base64
import html
import json
import re
from pathlib import Path
from typing import Any, Sequence

from pcmgn_jax.atomic import atomic_write_text

__all__ = ["ReportError", "load_run", "optimize_results", "render", "write_report"]

# the summary columns: (metrics key, header, optional key of the worst case shown in brackets)
COLUMNS = (("position_mae_um", "position MAE [µm]", None),
           ("stress_mae_mpa", "stress MAE [MPa]", None),
           ("oled_objective_area_rel_error_pct_mean", "OLED objective error, area mean [%] (worst design)",
            "oled_objective_area_rel_error_pct_max"),
           ("oled_objective_rel_error_pct_mean", "OLED objective error, node mean [%] (worst design)",
            "oled_objective_rel_error_pct_max"),
           ("penetration_max_um", "max penetration [µm]", None))
# the evaluation's figures first, in reading order; any other PNG after them by name
FIGURES = {"pred_truth_error.png": "von Mises: prediction, truth, |error| (and the OLED layer along x)",
           "oled_objective_vs_time.png": "OLED objective over time, prediction vs truth",
           "mae_vs_frame.png": "per-frame error with the impact phases",
           "contact_zoom.png": "contact zone at peak stress",
           "deformed_mesh_pred.png": "predicted deformed mesh at peak stress"}


class ReportError(ValueError):
    """A run directory the report cannot be made from (the message names the file and the command)."""


def _json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _last_jsonl(path: Path) -> dict | None:
    try:
        lines = [s for s in path.read_text(encoding="utf-8").splitlines() if s.strip()]
        return json.loads(lines[-1]) if lines else None
    except (OSError, ValueError):
        return None


def _pngs(folder: Path) -> list[tuple[str, bytes]]:
    names = sorted(p.name for p in folder.glob("*.png"))
    order = [n for n in FIGURES if n in names] + [n for n in names if n not in FIGURES]
    return [(n, (folder / n).read_bytes()) for n in order]


def optimize_results(run_dir: str | Path) -> list[Path]:
    """The result JSONs of ``experiments.optimize`` under ``RUN/opt*/`` (not the GA's ``.resume.json``
    files nor anything else that lacks an optimum), sorted by path."""
    out = []
    for p in sorted(Path(run_dir).glob("opt*/*.json")):
        d = None if p.name.endswith(".resume.json") else _json(p)
        if isinstance(d, dict) and {"method", "optimum_um", "predicted_mpa"} <= set(d):
            out.append(p)
    return out


def load_run(run_dir: str | Path, *, name: str = "") -> dict:
    """Everything the report shows, read from ``run_dir`` (see the module docstring); ``name``: the
    evaluation folder ``RUN/eval/NAME`` ("" = ``RUN/eval``, the run's test split). Raises
    :class:`ReportError` when that evaluation's metrics.json is missing or unreadable."""
    run = Path(run_dir)
    ev = run / "eval" / name if name else run / "eval"
    mpath = ev / "metrics.json"
    if not mpath.is_file():
        flag = f" --name {name}" if name else ""
        raise ReportError(f"{mpath}: no evaluation to report; make it with "
                          f"`python -m experiments.evaluate --workdir {run}{flag}` (or `pcmgn evaluate ...`)")
    metrics = _json(mpath)
    if not isinstance(metrics, dict):
        raise ReportError(f"{mpath}: not a metrics JSON of experiments.evaluate")
    config = _json(run / "config.json")
    data = _json(run / "data.json")
    dataset_dir = (data or {}).get("dataset_dir") or (
        (config or {}).get("dataset_dir") or f"data/{(config or {}).get('data_preset', 'cpu')}")
    manifest = _json(Path(dataset_dir) / "manifest.json")
    subs = {} if name else {p.parent.name: m for p in sorted((run / "eval").glob("*/metrics.json"))
                            if isinstance(m := _json(p), dict)}
    opt = [(p, _json(p)) for p in optimize_results(run)]
    opt_png = [(f"{p.parent.name}/{p.with_suffix('.png').name}", p.with_suffix(".png").read_bytes())
               for p, _ in opt if p.with_suffix(".png").is_file()]
    return {"run_dir": str(run), "eval_dir": str(ev), "metrics": metrics, "config": config, "data": data,
            "dataset_dir": str(dataset_dir), "manifest": manifest if isinstance(manifest, dict) else None,
            "train_log": _last_jsonl(run / "metrics.jsonl"), "images": _pngs(ev), "sub_evals": subs,
            "optimize": opt, "optimize_images": opt_png}


# ---------------------------------------------------------------------------------------------- HTML
e = html.escape


def _num(v, fmt: str = ".4g") -> str:
    if isinstance(v, bool) or v is None:
        return e(str(v))
    if isinstance(v, (int, float)):
        return format(v, fmt) if isinstance(v, float) else f"{v:,}"
    return e(str(v))


def _table(head: Sequence[str], rows: Sequence[Sequence[str]], *, cls: str = "") -> str:
    """An HTML table; ``head`` is plain text (escaped here), ``rows`` cells are HTML already (a cell
    ``(html, n)`` spans n columns)."""
    th = "".join(f"<th>{e(h)}</th>" for h in head)
    def td(c):
        return f'<td colspan={c[1]} class=span>{c[0]}</td>' if isinstance(c, tuple) else f"<td>{c}</td>"
    body = "".join("<tr>" + "".join(map(td, r)) + "</tr>" for r in rows)
    return f'<table class="{cls}"><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>'


def _inline(text: str) -> str:
    """Escaped text with markdown ``code`` and **bold** spans (the Table-8 lines' markup)."""
    out = e(text)
    out = re.sub(r"`([^`]*)`", r"<code>\1</code>", out)
    return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", out)


def _markdown_html(lines: Sequence[str]) -> str:
    """Markdown tables, bullet lines and paragraphs (what :func:`pcmgn_jax.opt.table.rows` writes) as HTML."""
    out, i = [], 0
    lines = list(lines)
    while i < len(lines):
        line = lines[i]
        if line.startswith("|"):
            block = []
            while i < len(lines) and lines[i].startswith("|"):
                block.append([c.strip() for c in lines[i].strip().strip("|").split("|")])
                i += 1
            body = [r for r in block[1:] if not all(set(c) <= set("-: ") for c in r)]
            th = "".join(f"<th>{_inline(c)}</th>" for c in block[0])
            tb = "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>" for r in body)
            out.append(f"<table><thead><tr>{th}</tr></thead><tbody>{tb}</tbody></table>")
            continue
        if line.startswith("- "):
            items = []
            while i < len(lines) and lines[i].startswith("- "):
                items.append(f"<li>{_inline(lines[i][2:])}</li>")
                i += 1
            out.append("<ul>" + "".join(items) + "</ul>")
            continue
        if line.strip():
            out.append(f"<p>{_inline(line)}</p>")
        i += 1
    return "\n".join(out)


def _predictors(m: dict) -> list[tuple[str, dict]]:
    return [("MGN", m)] + list((m.get("baselines") or {}).items())


def summary_html(m: dict) -> str:
    """The model beside every baseline: the :data:`COLUMNS` plus seconds per design; the best value of a
    column in bold (lowest; 'none', the nothing-moves floor, is not a contender)."""
    preds = _predictors(m)
    best = {}
    for key, _, _ in COLUMNS:
        vals = [v[key] for n, v in preds if n != "none" and isinstance(v.get(key), (int, float))]
        best[key] = min(vals) if vals else None
    rows = []
    for name, v in preds:
        if "not_applicable" in v:
            rows.append([e(name), (f"n/a: {e(str(v['not_applicable']))}", len(COLUMNS) + 1)])
            continue
        cells = [f"<b>{e(name)}</b>" if name == "MGN" else e(name)]
        for key, _, worst in COLUMNS:
            if not isinstance(v.get(key), (int, float)):
                cells.append("–")
                continue
            text = _num(v[key]) + (f" ({_num(v[worst])})" if worst and isinstance(v.get(worst), (int, float)) else "")
            cells.append(f"<b>{text}</b>" if v[key] == best[key] and name != "none" else text)
        sec = v.get("rollout_seconds_per_trajectory" if name == "MGN" else "predict_seconds_per_trajectory")
        cells.append(_num(sec) if isinstance(sec, (int, float)) else "–")
        rows.append(cells)
    if "penetration_max_um_truth" in m:
        rows.append(["ground truth (solver)"] + ["–"] * (len(COLUMNS) - 1)
                    + [_num(m["penetration_max_um_truth"]), "–"])
    head = ["predictor"] + [h for _, h, _ in COLUMNS] + ["s / design"]
    return _table(head, rows, cls="metrics")


def per_part_html(m: dict) -> str:
    parts = m.get("per_part") or {}
    if not parts:
        return "<p>No per-part errors in this metrics.json.</p>"
    rows = [[e(p), _num(v.get("position_mae_um")), _num(v.get("stress_mae_mpa"))] for p, v in parts.items()]
    return _table(["part", "position MAE [µm]", "stress MAE [MPa]"], rows)


def _design_labels(manifest: dict | None, n: int) -> list[str] | None:
    """The test designs (µm; family scenes with their parameters) in the order evaluation loads them
    (the first ``n`` of DIR/test by name), from the manifest; None when there is none."""
    try:
        tr = sorted(manifest["splits"]["test"]["trajectories"], key=lambda t: t["name"])[:n]
    except (TypeError, KeyError):
        return None
    if len(tr) < n:
        return None
    out = []
    for t in tr:
        label = " / ".join(f"{x:.1f}" for x in t.get("design_um", []))
        extra = {k: v for k, v in (t.get("scene_params") or {}).items() if k.startswith("ball.")}
        if extra:
            label += " (" + ", ".join(f"{k} {v * 1e3:.3f} mm" if k.endswith("radius") else f"{k} {v:.3f} m/s"
                                      for k, v in extra.items()) + ")"
        out.append(f"{t['name']}: {label}")
    return out


def objective_html(m: dict, manifest: dict | None) -> str:
    """The OLED objective per test design, truth vs MGN, both readings (and the objective surfaces' own
    predictions, kriging / MOP, where the metrics hold them)."""
    readings = [(k, lab) for k, lab in (("oled_objective_area", "area mean"), ("oled_objective", "node mean"))
                if f"{k}_true_mpa" in m]
    if not readings:
        return "<p>No OLED objective in this metrics.json (the scene has no part named OLED).</p>"
    n = len(m[f"{readings[0][0]}_true_mpa"])
    labels = _design_labels(manifest, n) or [f"test design {i}" for i in range(n)]
    surfaces = [(name, v) for name, v in (m.get("baselines") or {}).items()
                if f"{readings[0][0]}_pred_mpa" in v]
    head = ["test design (T1 / T2 … [µm])"]
    for _, lab in readings:
        head += [f"{lab}: truth [MPa]", f"{lab}: MGN [MPa]", f"{lab}: MGN error [%]"]
    head += [f"{readings[0][1]}: {name} [MPa]" for name, _ in surfaces]
    rows = []
    for i in range(n):
        r = [e(labels[i])]
        for k, _ in readings:
            t, p = m[f"{k}_true_mpa"][i], m[f"{k}_pred_mpa"][i]
            r += [_num(t), _num(p), _num(abs(p - t) / max(abs(t), 1e-12) * 100, ".3g")]
        r += [_num(v[f"{readings[0][0]}_pred_mpa"][i]) for _, v in surfaces]
        rows.append(r)
    return _table(head, rows)


def _flat(d: dict, prefix: str = "") -> list[tuple[str, Any]]:
    out = []
    for k, v in d.items():
        if isinstance(v, dict):
            out += _flat(v, f"{prefix}{k}.")
        else:
            out.append((f"{prefix}{k}", v))
    return out


def _kv(d: dict) -> str:
    rows = [[f"<code>{e(k)}</code>", e(json.dumps(v, ensure_ascii=False) if not isinstance(v, str) else v)]
            for k, v in _flat(d)]
    return _table(["key", "value"], rows, cls="kv")


def provenance_html(run: dict) -> str:
    parts = [f"<p>Dataset directory: <code>{e(run['dataset_dir'])}</code></p>"]
    man, data = run.get("manifest"), run.get("data")
    if man:
        fam = man.get("family")
        parts.append(f"<p>Solver preset <code>{e(str(man.get('preset')))}</code>; design layers "
                     f"{e(', '.join(man.get('design_layers') or []))}"
                     + (f"; scene family over {e(', '.join(p[0] for p in fam['parameters']))}" if fam else "")
                     + ".</p>")
        rows = []
        for split, s in (man.get("splits") or {}).items():
            o = s.get("origin") or {}
            origin = ", ".join(f"{k} {json.dumps(v)}" for k, v in o.items())
            rows.append([e(split), _num(len(s.get("trajectories") or [])), e(origin)])
        parts.append(_table(["split", "trajectories", "origin"], rows))
        layers = (man.get("scene") or {}).get("layers") or []
        if layers:
            parts.append("<h3>Scene layers</h3>" + _table(
                ["layer", "E [GPa]", "ν", "thickness [µm]", "density [kg/m³]"],
                [[e(str(L.get("name"))), _num(L.get("youngs", 0) * 1e-9), _num(L.get("poisson")),
                  _num(L.get("thickness", 0) * 1e6), _num(L.get("density"))] for L in layers]))
    else:
        parts.append(f"<p>No <code>manifest.json</code> in <code>{e(run['dataset_dir'])}</code> (an imported "
                     "dataset, or the directory is gone).</p>")
    if data:
        rows = [[e(split), e(str(t.get("name"))), e(str(t.get("source"))), _num(t.get("n_nodes")),
                 f"<code>{e(str(t.get('sha256') or '–')[:16])}</code>"]
                for split in ("train", "val") for t in data.get(split) or []]
        parts.append(f"<h3>Trajectories the run trained and validated on (<code>data.json</code>, source "
                     f"{e(str(data.get('source')))})</h3>"
                     + _table(["split", "name", "source", "nodes", "sha256 (first 16)"], rows))
    else:
        parts.append("<p>No <code>data.json</code> in the run directory.</p>")
    return "\n".join(parts)


def _img(name: str, png: bytes, caption: str) -> str:
    src = "data:image/png;base64," + base64.b64encode(png).decode("ascii")
    return (f'<figure><img src="{src}" alt="{e(name)}"><figcaption><code>{e(name)}</code>: '
            f"{e(caption)}</figcaption></figure>")


CSS = """body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;margin:.8em 0;font-size:.9em}th,td{border:1px solid #ccc;padding:.25em .5em;
text-align:right}th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}
table.kv td,td.span{text-align:left}code{background:#f5f5f5;padding:0 .2em}figure{margin:1em 0}
img{max-width:100%;border:1px solid #ddd}figcaption{font-size:.85em;color:#555}.note{color:#555}"""


def render(run: dict, *, optimize_table: Sequence[str] | None = None, title: str = "") -> str:
    """The report of :func:`load_run`'s ``run`` as one HTML string; ``optimize_table``: the Table-8 lines
    (:func:`pcmgn_jax.opt.table.rows`) of the run's optimise results, or None."""
    m = run["metrics"]
    title = title or f"pcmgn_jax run report: {run['run_dir']}"
    info = [f"{m.get('n_test', '?')} test trajectories", f"{m.get('n_frames', '?')} frames",
            f"{m.get('n_nodes', '?')} graph nodes", f"checkpoint {m.get('checkpoint', '?')}",
            f"contact projection {'on' if m.get('contact_projection') else 'off'}"]
    log = run.get("train_log")
    if log:
        info.append(f"training's last log line: step {log.get('step')}, loss {_num(log.get('loss'))}")
    body = [f"<h1>{e(title)}</h1>",
            f"<p class=note>Evaluation <code>{e(run['eval_dir'])}/metrics.json</code>: "
            f"{e('; '.join(map(str, info)))}.</p>",
            "<h2>Metrics beside the baselines</h2>",
            "<p class=note>Rollouts from frame 0 over the test split; every baseline fitted on the run's training "
            "split and scored by the same code (<code>pcmgn_jax.metrics</code>). Bold: the best of a column.</p>",
            summary_html(m)]
    warns = [str(w) for v in (m.get("baselines") or {}).values() for w in v.get("warnings") or []]
    if warns:   # each names its baseline
        body.append(f"<details><summary>{len(warns)} baseline warnings</summary><ul>"
                    + "".join(f"<li>{e(w)}</li>" for w in warns) + "</ul></details>")
    body += ["<h2>OLED objective per test design</h2>", objective_html(m, run.get("manifest")),
             "<h2>Errors per part (MGN)</h2>", per_part_html(m)]
    body.append("<h2>Plots</h2>")
    if run.get("images"):
        body += [_img(n, png, FIGURES.get(n, "")) for n, png in run["images"]]
    else:
        body.append("<p>No PNG plots in the evaluation folder.</p>")
    if run.get("optimize"):
        body.append("<h2>Design optimisation (Table 8 of the paper, this run's results)</h2>")
        body.append(_markdown_html(optimize_table) if optimize_table else
                    "<p>" + e(", ".join(str(p) for p, _ in run["optimize"])) + "</p>")
        body += [_img(n, png, "objective map") for n, png in run.get("optimize_images") or []]
    if run.get("sub_evals"):
        body.append("<h2>Other evaluations of this run</h2>")
        for name, sm in run["sub_evals"].items():
            body += [f"<details><summary><code>eval/{e(name)}</code> ({_num(sm.get('n_test', '?'))} "
                     f"trajectories)</summary>", summary_html(sm), "</details>"]
    body += ["<h2>Data provenance</h2>", provenance_html(run), "<h2>Configuration (<code>config.json</code>)</h2>",
             _kv(run["config"]) if isinstance(run.get("config"), dict)
             else "<p>No config.json in the run directory.</p>"]
    return ("<!DOCTYPE html>\n<html lang=en><head><meta charset=utf-8><title>" + e(title) + "</title><style>"
            + CSS + "</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


def write_report(run_dir: str | Path, out: str | Path | None = None, *, name: str = "",
                 optimize_table: Sequence[str] | None = None) -> Path:
    """Write the report of ``run_dir`` to ``out`` (default RUN/report.html, or RUN/report_NAME.html for
    ``name``) atomically and return its path. Raises :class:`ReportError` as :func:`load_run`."""
    run = load_run(run_dir, name=name)
    path = Path(out) if out else Path(run_dir) / (f"report_{name}.html" if name else "report.html")
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, render(run, optimize_table=optimize_table))
    return path
