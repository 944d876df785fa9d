"""The paper's studies (its Tables 3-7 and §4.6), in its formulation and in the project's default.

Studies (:data:`STUDIES`): lambda (penetration weight), degree (polynomial degrees of the boundary fits),
noise_sigma (noise magnitude, all parts), noise_parts (which bodies get 0.3 µm noise), target (what the
model predicts), extrapolation (λ = 0 vs 10, evaluated on the paper's four designs outside the training
box, DATA/extrap, generated on first use). Every cell is a training run of the cpu preset with the
formulation's base settings (:data:`BASE`), the study's settings for that formulation (:data:`FORM_SETTINGS`),
the cell's settings and ``num_steps`` (trimmed so a study fits in about an hour: steps, not seeds, are
cut), then the evaluation (:func:`pcmgn_jax.studies.cells.run_cell`: finished cells are never retrained
and a killed training resumes). Settings are :meth:`TrainConfig.from_preset` keyword arguments (later
ones win); tables and records write them as training flags (:func:`pcmgn_jax.studies.cells.as_flags`).

:func:`run` writes OUT/<name>.{json,md} (a table beside the paper's numbers, mean ± std over seeds) and
<name>_per_frame.png (per-frame position MAE per cell, like the paper's Figure 7) after every cell. A run
of some formulations keeps the other formulations' rows of the study's earlier JSON (with the command that
measured them); the earlier JSON's note is dropped with the rows it was about. :func:`render` re-writes
the table and plot from the JSON.
"""
from __future__ import annotations

from pathlib import Path

from pcmgn_jax import markdown
from pcmgn_jax.studies import cells

# base settings per formulation: the paper's (0.3 µm noise on all nodes, lambda = 10) and the project's
# default (the cpu preset's own settings: quasi-static panel, its noise and lambda)
BASE = {"paper": {"formulation": "paper", "noise_std": 3e-7, "noise_rel": 0.0, "noise_parts": "all",
                  "lambda_pen": 10.0},
        "default": {"formulation": "default"}}

# study -> (paper table, default steps, [(cell, settings, paper (position MAE µm, stress MAE MPa) of the
# physics-constrained MGN, of the vanilla MGN or None)])
STUDIES = {
    "lambda": ("Table 5", 1000, [
        ("none (0)", {"lambda_pen": 0.0}, (0.704, 0.9775), None),
        ("0.1", {"lambda_pen": 0.1}, (0.783, 0.826), None),
        ("1", {"lambda_pen": 1.0}, (0.830, 0.717), None),
        ("10", {"lambda_pen": 10.0}, (0.309, 0.547), None),
        ("30", {"lambda_pen": 30.0}, (0.583, 0.964), None)]),
    "degree": ("Table 4", 500, [
        (f"B.{b}/P.{p}", {"poly_ball": b, "poly_panel": p}, v, None) for (b, p), v in {
            (2, 3): (1.420, 1.314), (2, 5): (0.539, 1.111), (2, 7): (1.273, 1.276), (4, 3): (0.471, 1.033),
            (4, 5): (0.626, 1.162), (4, 7): (0.909, 1.054), (6, 5): (0.309, 0.547), (6, 7): (0.545, 0.718)}.items()]),
    "noise_sigma": ("Table 6", 1000, [
        (f"{s} µm", {"noise_std": float(f"{s * 1e-6:g}"), "noise_rel": 0.0, "noise_parts": "all"}, c, v)
        for s, c, v in ((0.1, (1.203, 1.685), (3.458, 2.588)), (0.3, (0.309, 0.547), (0.704, 0.978)),
                        (0.7, (1.421, 1.786), (0.915, 0.953)), (1.5, (1.504, 1.815), (1.806, 1.551)))]),
    "noise_parts": ("Table 7", 1000, [
        (p, {"noise_std": 3e-7, "noise_rel": 0.0, "noise_parts": p}, c, v)
        for p, c, v in (("none", (3.826, 4.465), (2.536, 4.431)), ("ball", (3.020, 4.747), (6.456, 4.119)),
                        ("panel", (7.166, 5.380), (6.685, 4.397)), ("all", (0.309, 0.547), (0.704, 0.978)))]),
    "target": ("Table 8 (output quantity)", 1500, [
        # the paper's per-step targets need a panel whose own state is an input (panel_model=dynamic; a
        # no-op for the paper's formulation); the default's quasi-static panel predicts its total field
        (t, {"ball_target": t, "panel_target": t, "panel_model": "dynamic"}, c, v)
        for t, c, v in (("position", (1318.342, 34.451), (1458.494, 59.638)),
                        ("displacement", (0.485, 0.797), (1.051, 1.130)),
                        ("velocity", (0.309, 0.547), (0.704, 0.978)))]),
    "extrapolation": ("§4.6 (figure only: no numbers)", 2000, [
        ("vanilla (λ = 0)", {"lambda_pen": 0.0}, None, None),
        # the penalty from step 0, as the paper's constrained model: at the cpu preset's half-way start a
        # cell whose best validation checkpoint is the middle one was scored before its penalty began
        ("constrained (λ = 10)", {"lambda_pen": 10.0, "lambda_start": 0.0}, None, None)]),
}
# settings a study adds for one formulation only: the default trains without the penetration term (its
# contact projection replaces it), so the boundary fits' degrees would change nothing there; the degree
# study gives it the paper's lambda = 10 so the fits enter its loss. The cpu preset starts the penalty
# half-way (lambda_start = 0.5); the lambda and target studies' paper formulation has it from step 0, as
# the paper (the extrapolation study's constrained cell too, in both formulations; the other studies'
# paper cells keep the half-way start they were measured with: their tables say so)
FORM_SETTINGS = {("degree", "default"): {"lambda_pen": 10.0}, ("lambda", "paper"): {"lambda_start": 0.0},
                 ("target", "paper"): {"lambda_start": 0.0}}
# cells that are the same training as another cell of the study, so they are not trained twice: the
# default's quasi-static panel never sees its own state (mgn.formulation.model_inputs draws the layers
# at their reference) and its total-displacement target needs no noise correction, so noise on the
# panel changes neither its inputs nor its loss (tests/train/test_noise.py)
SAME_AS = {("noise_parts", "default"): ({"panel": "none", "all": "ball"}, "the quasi-static panel's own state is "
                                         "not an input, so panel noise changes neither the inputs nor the loss")}
EXTRAP_DESIGNS_UM = "40,40;40,160;160,40;160,160"   # the paper's §4.6
STUDY_METRICS = ("position_mae_um", "stress_mae_mpa", "oled_objective_area_rel_error_pct_mean", "penetration_max_um")


def _slug(s: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in s).strip("_")


def _check(name: str, forms) -> None:
    if name not in STUDIES:
        raise ValueError(f"study name={name!r} must be one of {list(STUDIES)}")
    bad = sorted(set(forms) - set(BASE))
    if bad:
        raise ValueError(f"study formulations: unknown {bad}; choose from {list(BASE)}")


def cell_settings(name: str, form: str, settings: dict, *, data: str, steps: int, seed: int) -> dict:
    """The training settings of one cell of study ``name`` in formulation ``form``: the cpu preset on the
    dataset ``data``, ``steps`` optimiser steps, ``seed``, then :data:`BASE`, :data:`FORM_SETTINGS` and
    the cell's ``settings`` (later ones win)."""
    return {"preset": "cpu", "dataset_dir": data, "num_steps": steps, "seed": seed, **BASE[form],
            **FORM_SETTINGS.get((name, form), {}), **settings}


def render(name: str, *, out: str | Path = "results/studies") -> None:
    """Re-write OUT/<name>.{md,png} (and its JSON) from OUT/<name>.json without running a cell, e.g. after
    the table's format changed. Raises ``FileNotFoundError`` when the study has no results yet."""
    import json
    _check(name, ())
    table_ref, _, study_cells = STUDIES[name]
    src = Path(out) / f"{name}.json"
    if not src.exists():
        raise FileNotFoundError(f"{src}: no study results to render (run the study first)")
    d = json.loads(src.read_text())
    write(name, out, table_ref, d["num_steps"], study_cells, list(d["results"]), d["seeds"], d["results"],
          command=d["command"], note=d.get("note"), kept=d.get("kept"))


def run(name: str, *, formulations=("paper", "default"), seeds=(0, 1), num_steps: int = 0,
        runs: str | Path = "runs/studies", out: str | Path = "results/studies", data: str = "data/cpu",
        command: str = "") -> dict:
    """Run study ``name`` (:data:`STUDIES`) in ``formulations`` (paper | default) over training ``seeds``
    (same data for all) at ``num_steps`` steps per cell (0: the study's trimmed default), cells under
    RUNS/<name>/<formulation>/<cell>_s<seed>, tables and plots in ``out``; ``command`` is recorded as the
    one that measured the cells. Returns {formulation: {cell: {seed: metrics}}} of this run."""
    forms = list(formulations)
    seeds = [int(s) for s in seeds]
    _check(name, forms)
    table_ref, steps, study_cells = STUDIES[name]
    cells.use_compilation_cache(Path(runs) / ".xla_cache")
    steps = num_steps or steps
    kept_results, kept = _kept(name, out, forms, steps, seeds)
    extra = None
    if name == "extrapolation":
        from pcmgn_jax.data.dataset import ensure_dataset
        from pcmgn_jax.data.designs import parse_designs
        ensure_dataset(data, preset="cpu", designs=parse_designs(EXTRAP_DESIGNS_UM), split="extrap")
        extra = {"extrap": str(Path(data) / "extrap")}
    results: dict = {}
    report = dict(name=name, out=out, table_ref=table_ref, steps=steps, study_cells=study_cells, forms=forms,
                  seeds=seeds, results=results, command=command, kept_results=kept_results, kept=kept)
    for form in forms:
        for label, settings, _, _ in study_cells:
            same = SAME_AS.get((name, form), ({}, ""))[0].get(label)
            if same is not None:   # the same training as an earlier cell of the study: its results
                results[form][label] = results[form][same]
                continue
            for seed in seeds:
                wd = Path(runs) / name / form / f"{_slug(label)}_s{seed}"
                m = cells.run_cell(wd, cell_settings(name, form, settings, data=data, steps=steps, seed=seed),
                                   extra_data=extra)
                src = m["eval_extrap"] if extra else m
                results.setdefault(form, {}).setdefault(label, {})[str(seed)] = {
                    **{k: src.get(k) for k in STUDY_METRICS}, "train_seconds": m["train_seconds"],
                    "checkpoint_step": m.get("checkpoint_step"),
                    "per_frame_position_mae_um_mean": src["per_frame_position_mae_um_mean"],
                    "baselines": src.get("baselines", {})}
                print(f"{name} {form} {label} seed {seed}: "
                      + ", ".join(f"{k}={src.get(k, float('nan')):.4g}" for k in STUDY_METRICS), flush=True)
                # the table after every cell: a study cut short still leaves what it has measured
                _write_all(**report, quiet=True)
    _write_all(**report)
    return results


def _kept(name, out, forms, steps, seeds) -> tuple[dict, dict]:
    """The formulations of an earlier run of this study (OUT/<name>.json) that this run does not re-run:
    their results and the command that measured them, so ``--formulations default`` re-measures the
    default rows and keeps the paper's. Refused when they were measured at other steps or seeds (the
    table has one of each)."""
    import json
    src = Path(out) / f"{name}.json"
    if not src.exists():
        return {}, {}
    d = json.loads(src.read_text())
    old = {f: r for f, r in d["results"].items() if f not in forms}
    if not old:
        return {}, {}
    if d["num_steps"] != steps or list(d["seeds"]) != seeds:
        raise ValueError(f"{src}: its {sorted(old)} rows were measured at {d['num_steps']} steps, seeds "
                         f"{d['seeds']}; this run is {steps} steps, seeds {seeds}. Pass --num_steps "
                         f"{d['num_steps']} --seeds {','.join(map(str, d['seeds']))}, or re-run every formulation.")
    prev = d.get("kept") or {}
    return old, {f: prev.get(f, d["command"]) for f in old}


def _write_all(name, out, table_ref, steps, study_cells, forms, seeds, results, command, kept_results, kept,
               quiet=False):
    """``write`` with the kept formulations' rows beside this run's, in BASE's order."""
    merged = {f: (results[f] if f in results else kept_results[f]) for f in BASE
              if f in results or f in kept_results}
    order = [f for f in BASE if f in forms or f in kept_results]
    write(name, out, table_ref, steps, study_cells, order, seeds, merged, command=command, quiet=quiet,
          kept=kept or None)


def ordering_lines(results, forms, study_cells) -> list[str]:
    """Per formulation: its best cell by position MAE beside the paper's best, and Kendall's tau between
    the cells' mean position (and stress) MAE and the paper's, over the cells measured here that the
    paper reports (orderings are what compare across data sets; values are not)."""
    import numpy as np
    from scipy.stats import kendalltau
    out = []
    paper_best = min((c for c in study_cells if c[2] is not None), key=lambda c: c[2][0], default=None)
    for form in [f for f in forms if results.get(f)]:
        mean = {label: [float(np.mean([m[k] for m in results[form][label].values()]))
                        for k in ("position_mae_um", "stress_mae_mpa")]
                for label, *_ in study_cells if results[form].get(label)}
        best = min(mean, key=lambda c: mean[c][0])
        line = f"- {form}: best cell by position MAE **{best}**"
        if paper_best is not None:
            line += f" (paper: {paper_best[0]}, {'the same' if best == paper_best[0] else 'not the same'})"
            both = [c for c in study_cells if c[2] is not None and c[0] in mean]
            if len(both) >= 3:
                taus = [kendalltau([mean[c[0]][k] for c in both], [c[2][k] for c in both]).statistic for k in (0, 1)]
                fmt = lambda t: "undefined (all cells equal)" if np.isnan(t) else f"{t:+.2f}"  # noqa: E731
                line += (f"; rank agreement with the paper over {len(both)} cells, Kendall's tau: position "
                         f"{fmt(taus[0])}, stress {fmt(taus[1])}")
        out.append(line)
    return out


def write(name, out, table_ref, steps, study_cells, forms, seeds, results, *, command: str, quiet: bool = False,
          note: str | None = None, kept: dict | None = None) -> None:
    """The table, JSON and per-frame plot of ``results`` ({formulation: {cell: {seed: metrics}}}); cells
    or seeds not measured yet are marked in the table (the runner writes after every cell); files
    OUT/<name>.{md,json} and OUT/<name>_per_frame.png. ``command`` is the one that measured the cells,
    except the formulations in ``kept`` ({formulation: the earlier command that measured them}); ``note``
    is kept in the JSON and quoted under the table's title. The caller picks the matplotlib backend."""
    import matplotlib.pyplot as plt
    import numpy as np

    from pcmgn_jax.atomic import atomic_write_json, atomic_write_text
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    where = "the paper's four extrapolation designs (data/cpu/extrap)" if name == "extrapolation" else \
        "the cpu test split (6 designs)"
    lines = [f"# Study `{name}` (paper {table_ref})", "", *([f"> {note}", ""] if note else []),
             f"`{command}`: cpu preset, {steps} steps per cell (trimmed to fit about an hour; the paper trained "
             f"~20 h on a GPU), seeds {seeds}, scored on {where}; mean ± std over seeds. Position and stress MAE "
             "in µm and MPa; objective error: the section area mean (docs/design.md §8). Every cell is scored with "
             "its best checkpoint by validation position MAE; a cell whose best is not its last step says so. "
             "A penetration term (λ > 0) starts half-way through training (the cpu preset's lambda_start = 0.5) "
             "unless the study adds `--lambda_start=0` below. "
             "The paper's numbers are "
             "its physics-constrained MGN (vanilla in brackets) on its data: compare orderings, not values."
             + "".join(f" The `{f}` formulation adds `{' '.join(cells.as_flags(v))}` in this study."
                       for (n, f), v in FORM_SETTINGS.items()
                       if n == name and f in forms)
             + "".join(f" The `{f}` rows are kept from an earlier run, `{c}`." for f, c in (kept or {}).items()), ""]
    done = sum(len(results.get(f, {}).get(c[0], {})) for f in forms for c in study_cells)
    total = len(forms) * len(study_cells) * len(seeds)
    if done < total:
        lines += [f"**Partial: {done} of {total} cell-seeds measured so far** "
                  "(the runner resumes where it stopped).", ""]
    rows = []
    for form in forms:
        for label, _, pc, pv in study_cells:
            per = list(results.get(form, {}).get(label, {}).values())
            paper = ("–" if pc is None
                     else f"{pc[0]:g} / {pc[1]:g}" + ("" if pv is None else f" ({pv[0]:g} / {pv[1]:g})"))
            if not per:
                rows.append((form, label, "not run yet", "", "", "", "", paper))
                continue
            tag = "" if len(per) == len(seeds) else f" ({len(per)} of {len(seeds)} seeds)"
            early = [m.get("checkpoint_step") for m in per]
            if any(c is not None and c < steps for c in early):   # scored on a model before the last step
                tag += f" (best checkpoint: step {', '.join('?' if c is None else str(c) for c in early)} of {steps})"
            same_as, why = SAME_AS.get((name, form), ({}, ""))
            if label in same_as:
                tag += f" (= {same_as[label]}, not retrained: {why})"
            rows.append((form, f"{label}{tag}", *(cells.mean_pm(m[k] for m in per) for k in STUDY_METRICS),
                         cells.mean_pm(m["train_seconds"] for m in per), paper))
    first = next(iter(next(iter(results.values())).values()))
    base = next(iter(first.values()))["baselines"]
    for kind, b in base.items():
        if "not_applicable" not in b:
            rows.append(("baseline", kind, *(f"{b.get(k, float('nan')):.3g}" for k in STUDY_METRICS), "–", "–"))
    lines += markdown.table(("formulation", "cell", "position MAE", "stress MAE", "objective error [%]",
                             "max penetration [µm]", "train [s]", "paper: position / stress"), rows)
    # the orderings: the best cell per formulation and the paper's, and how far the cells' ranking agrees
    # with the paper's (Kendall's tau over the cells both have: +1 the same order, -1 reversed)
    lines.append("")
    lines += ordering_lines(results, forms, study_cells)
    atomic_write_text(out / f"{name}.md", "\n".join(lines) + "\n")
    atomic_write_json(out / f"{name}.json", {"command": command, "num_steps": steps, "seeds": seeds,
                                            "base_flags": {f: cells.as_flags(BASE[f]) for f in forms},
                                            "results": results, **({"note": note} if note else {}),
                                            **({"kept": kept} if kept else {})})
    fig, axes = plt.subplots(1, len(forms), figsize=(5.5 * len(forms), 3.8), squeeze=False)
    for ax, form in zip(axes[0], forms):
        for label, *_ in study_cells:
            if not results.get(form, {}).get(label):
                continue
            curves = np.array([m["per_frame_position_mae_um_mean"] for m in results[form][label].values()])
            ax.plot(curves.mean(0), label=label)
        ax.set(title=f"{name}: {form} formulation", xlabel="frame", ylabel="position MAE [µm]", yscale="log")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / f"{name}_per_frame.png", dpi=110)
    plt.close(fig)
    if not quiet:
        print("\n".join(lines))
