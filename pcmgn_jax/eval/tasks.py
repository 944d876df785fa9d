"""The four-task comparison: the MGN beside every baseline, per task, with the winner per metric.

    rows = task_rows({"a": [m_seed0, m_seed1], "b": [m]})   # evaluate()'s metrics.json dicts per task
    text = task_table(rows, commands)                      # Markdown

Tasks (:data:`TASKS`): (a) the paper's box (``cpu`` test split), (b) the scene family's test split,
(c) extrapolation (designs / scenes outside the training box), (d) zero-shot (scenes varying a parameter
training held fixed); ``T.VARIANT`` keys (``d.cg_thin``) give a task one table per variant. A task
with no metrics is listed as not measured. Per predictor and metric: the
mean over the given seeds' files (the baselines are deterministic, so their seeds agree), with the
MGN's range over the seeds in brackets, and the worst design's error where metrics.json has it (``*_max``). Lower is
better for every metric.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from pcmgn_jax import markdown

TASKS = {"a": "the paper's box (cpu test split)", "b": "scene family (family test split)",
         "c": "extrapolation (outside the training box)", "d": "zero-shot (a parameter training held fixed)",
         "e": "new panel stacks (stack family: e.e1 in distribution, e.e2 a held-out layer count, e.e3 an impactor "
              "outside the trained range)"}
METRICS = (("position_mae_um", "position MAE [µm]"), ("stress_mae_mpa", "stress MAE [MPa]"),
           ("oled_objective_area_rel_error_pct_mean", "objective error, area mean [%]"),
           ("oled_objective_area_rel_error_pct_max", "worst design [%]"),
           ("penetration_max_um", "max penetration [µm]"))
WINNER_METRICS = ("position_mae_um", "stress_mae_mpa", "oled_objective_area_rel_error_pct_mean")


def _predictors(m: dict) -> dict[str, dict]:
    out = {"MGN": m}
    out.update({k: v for k, v in m.get("baselines", {}).items() if "not_applicable" not in v})
    return out


def mean_rows(files: Sequence[dict]) -> dict[str, dict[str, float]]:
    """{predictor: {metric: mean over ``files``}} of evaluate()'s metrics.json dicts (the predictors
    that answered), plus ``{metric}_seeds`` [min, max] for the MGN when more than one file is given."""
    acc: dict[str, dict[str, list]] = {}
    for m in files:
        for name, v in _predictors(m).items():
            for key, _ in METRICS:
                if isinstance(v.get(key), (int, float)):
                    acc.setdefault(name, {}).setdefault(key, []).append(float(v[key]))
    out = {name: {k: float(np.mean(x)) for k, x in d.items()} for name, d in acc.items()}
    if len(files) > 1 and "MGN" in acc:
        out["MGN"].update({f"{k}_seeds": [float(min(x)), float(max(x))] for k, x in acc["MGN"].items()})
    corrected = {m.get("residual_of") or "" for m in files}
    if len(corrected) > 1:
        raise ValueError(f"one task's metrics files mix MGNs that predict the fields and corrections of a baseline "
                         f"(residual_of {sorted(corrected)}): give each its own T.VARIANT")
    if "MGN" in out and corrected != {""}:
        out["MGN"]["residual_of"] = corrected.pop()   # the MGN row is the network's correction of this baseline
    return out


def task_rows(runs: Mapping[str, Sequence[dict]]) -> dict[str, dict[str, dict[str, float]]]:
    """{task: :func:`mean_rows` of the task's metrics files}."""
    rows = {}
    for task, files in runs.items():
        if task.split(".", 1)[0] not in TASKS:
            raise ValueError(f"task must be one of {sorted(TASKS)} (or T.VARIANT, e.g. d.cg_thin), got {task!r}")
        rows[task] = mean_rows(files)
    return rows


TRUTH_KEYS = ("oled_objective_area_true_mpa", "oled_objective_true_mpa")   # a test split's fingerprint


def lend_baselines(files: Sequence[dict], source: dict, *, name: str = "the baselines' file") -> list[dict]:
    """``files`` (evaluate's metrics.json dicts; those evaluated with ``--no_baselines`` have none) with the
    baselines of ``source``, an evaluation of the same test split: the baselines do not depend on the MGN. The
    split is checked, not assumed: every file's test designs' true objectives must equal the source's (ValueError
    naming ``name`` otherwise). A file that scored its own baselines keeps them."""
    key = next((k for k in TRUTH_KEYS if k in source), None)
    if key is None or not source.get("baselines"):
        raise ValueError(f"{name}: no baselines and test truths to lend (it must be an evaluation that scored the "
                         "baselines)")
    out = []
    for i, m in enumerate(files):
        if m.get(key) is None or not np.array_equal(np.asarray(m[key]), np.asarray(source[key])):
            raise ValueError(f"{name}: its test split is not that of file {i + 1} of the task ({key} differ): "
                             "baselines are lent only within one test split")
        out.append(m if m.get("baselines") else {**m, "baselines": source["baselines"]})
    return out


def winners(row: dict[str, dict[str, float]]) -> dict[str, str]:
    """{metric: the predictor with the lowest value} among those that report it (ground truth excluded:
    'none' is a predictor too; ties go to the first listed)."""
    out = {}
    for key in WINNER_METRICS:
        have = [(v[key], name) for name, v in row.items() if key in v]
        if have:
            out[key] = min(have, key=lambda t: t[0])[1]
    return out


def task_table(rows: dict, commands: Mapping[str, str] = {}, seeds: Mapping[str, int] = {}) -> str:
    """Markdown: one section per task (not measured ones say so), predictors as rows, winners bold."""
    lines = []
    for base, title in TASKS.items():
        keys = [k for k in rows if k.split(".", 1)[0] == base and rows[k]]
        if not keys:
            lines += [f"### ({base}) {title}", "", "Not measured yet.", ""]
            continue
        for task in keys:
            variant = task.split(".", 1)[1] if "." in task else ""
            lines += [f"### ({base}) {title}" + (f": {variant}" if variant else ""), ""]
            head = ([f"`{commands[task]}`"] if task in commands else []) + \
                ([f"({seeds[task]} seed(s) of the MGN)"] if task in seeds else [])
            if head:
                lines += [" ".join(head), ""]
            if corrected_by := rows[task].get("MGN", {}).get("residual_of"):
                lines += [f"MGN here = the {corrected_by} baseline corrected by the network "
                          f"(`--residual_of={corrected_by}`, docs/design.md §5.2).", ""]
            lines += _table(rows[task])
    return "\n".join(lines)


def summary_table(rows: dict) -> str:
    """Markdown, one row per task (and variant): per winner metric the MGN's value, the best baseline's
    (named) and their ratio MGN / best (< 1: the MGN is the more accurate), so the whole comparison reads
    at a glance before the per-task tables."""
    labels = dict(METRICS)
    body = []
    for task, row in rows.items():
        if "MGN" not in row:
            continue
        cells = []
        for key in WINNER_METRICS:
            base = [(v[key], n) for n, v in row.items() if n != "MGN" and key in v]
            mgn = row["MGN"].get(key)
            if mgn is None or not base:
                cells.append("–")
                continue
            best, name = min(base, key=lambda t: t[0])
            ratio = f"{mgn / best:.2g}×" if best > 0 else "–"
            cell = f"{mgn:.3g} / {best:.3g} ({name}): {ratio}"
            cells.append(f"**{cell}**" if mgn <= best else cell)
        label = task + (f" (MGN = {row['MGN']['residual_of']} + correction)" if row["MGN"].get("residual_of") else "")
        body.append((label, *cells))
    head = ("task", *(f"{labels[k]}: MGN / best baseline" for k in WINNER_METRICS))
    return "\n".join(markdown.table(head, body))


def _table(row: dict[str, dict[str, float]]) -> list[str]:
    win = winners(row)
    body = []
    for name, v in row.items():
        cells = []
        for key, _ in METRICS:
            s = f"{v[key]:.3g}" if key in v else "–"
            s = f"**{s}**" if win.get(key) == name else s
            if f"{key}_seeds" in v:      # the MGN's seed range
                s += " ({:.3g}–{:.3g})".format(*v[f"{key}_seeds"])
            cells.append(s)
        body.append((name, *cells))
    named = ", ".join(f"{dict(METRICS)[k]}: **{n}**" for k, n in win.items())
    head = ("predictor", *(label for _, label in METRICS))
    verdict = (f"Winner per metric: {named}." if len(row) > 1 else
               "No baselines in these files (evaluated with `--no_baselines`): nothing to compare with.")
    return markdown.table(head, body) + ["", verdict, ""]


def code_note(runs: Mapping[str, Sequence[dict]]) -> str:
    """One line naming the code versions the metrics files come from (their ``code`` record, written by
    evaluate since it has one): a table whose files were made by different code says so."""
    counts: dict[str, int] = {}
    for files in runs.values():
        for m in files:
            c = m.get("code") or {}
            key = ("no code record (older files)" if not c.get("commit")
                   else c["commit"][:10] + (" (uncommitted changes)" if c.get("dirty") else ""))
            counts[key] = counts.get(key, 0) + 1
    parts = [f"{n} from {k}" for k, n in sorted(counts.items(), key=lambda kv: -kv[1])]
    warn = " — made by different code: compare with care" if len(counts) > 1 else ""
    return f"Code of the {sum(counts.values())} metrics files: {'; '.join(parts)}{warn}."
