"""The README's headline table is the committed main-job run (``results/runs/main/metrics.json``), cell for cell:
every figure in a predictor's row equals the run's metric rounded to the decimals the cell shows. The run itself is
what the README's own command makes on a clean clone (``results/runs/main/README.md`` says the commit and the
commands); a README edited by hand, or a run re-scored without the README, fails here."""
from __future__ import annotations

import json
import re

import pytest

from fixtures.helpers import ROOT

METRICS = json.loads((ROOT / "results" / "runs" / "main" / "metrics.json").read_text())

# README row label -> (where in metrics.json, the metrics each numeric cell shows, left to right)
ROWS = {
    "MGN (default formulation)": ((), ("position_mae_um", "stress_mae_mpa", "oled_objective_area_rel_error_pct_mean",
                                       "oled_objective_area_rel_error_pct_max", "rollout_seconds_per_trajectory")),
    "none (nothing moves)": (("baselines", "none"), ("position_mae_um", "stress_mae_mpa",
                                                     "oled_objective_area_rel_error_pct_mean")),
    "nearest training design": (("baselines", "nearest"), ("position_mae_um", "stress_mae_mpa",
                                                           "oled_objective_area_rel_error_pct_mean",
                                                           "oled_objective_area_rel_error_pct_max")),
    "per-node quadratic (poly2)": (("baselines", "poly2"), ("position_mae_um", "stress_mae_mpa",
                                                            "oled_objective_area_rel_error_pct_mean",
                                                            "oled_objective_area_rel_error_pct_max")),
    "kriging (objective surface; fields per node)": (("baselines", "kriging"), (
        "position_mae_um", "stress_mae_mpa", "oled_objective_area_rel_error_pct_mean",
        "oled_objective_area_rel_error_pct_max")),
    "POD reduced-order model (rom)": (("baselines", "rom"), ("position_mae_um", "stress_mae_mpa",
                                                             "oled_objective_area_rel_error_pct_mean",
                                                             "oled_objective_area_rel_error_pct_max")),
}
_NUM = re.compile(r"-?\d+(?:,\d{3})*(?:\.\d+)?")


def _readme_rows() -> dict[str, list[str]]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    head = text.index("## Headline result")
    rows = {}
    for line in text[head:].splitlines():
        if line.startswith("| ") and not line.startswith("| predictor") and not line.startswith("|---"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            rows[cells[0].replace("*", "")] = cells[1:]
    return rows


def _numbers(cells: list[str]) -> list[str]:
    out = []
    for cell in cells:
        out += _NUM.findall(cell.replace("*", ""))
    return out


@pytest.mark.parametrize("label", sorted(ROWS))
def test_the_readme_headline_row_is_the_committed_run(label):
    rows = _readme_rows()
    assert label in rows, f"README headline: no row {label!r} (rows: {sorted(rows)})"
    where, keys = ROWS[label]
    src = METRICS
    for k in where:
        src = src[k]
    shown = _numbers(rows[label])
    assert len(shown) >= len(keys), (label, rows[label])
    for key, text in zip(keys, shown):
        decimals = len(text.split(".")[1]) if "." in text else 0
        value = float(src[key])
        assert abs(float(text.replace(",", "")) - value) <= 0.5 * 10 ** -decimals + 1e-12, (
            f"README {label!r}: {key} shows {text}, the committed run has {value:.6g}")


def test_the_committed_run_is_of_the_current_element():
    """The headline run's data is the solver's current element (its README records the commit and element)."""
    from pcmgn_jax.sim.fem import DEFAULT_ELEMENT

    note = (ROOT / "results" / "runs" / "main" / "README.md").read_text(encoding="utf-8")
    assert f"element `{DEFAULT_ELEMENT}`" in note
