"""pcmgn_jax.eval.tasks: the four-task table from metrics.json dicts; winners per metric; missing tasks said."""
import json

import pytest

from pcmgn_jax.eval.tasks import task_rows, task_table, winners


def _m(pos, obj, base_pos, base_obj):
    return {"position_mae_um": pos, "stress_mae_mpa": 2.0, "oled_objective_area_rel_error_pct_mean": obj,
            "baselines": {"kriging": {"oled_objective_area_rel_error_pct_mean": base_obj},
                          "rom": {"position_mae_um": base_pos, "stress_mae_mpa": 3.0},
                          "poly2": {"not_applicable": "meshes differ"}}}


def test_rows_average_seeds_and_name_winners():
    rows = task_rows({"a": [_m(0.3, 2.0, 0.1, 0.05), _m(0.5, 4.0, 0.1, 0.05)], "b": [_m(0.5, 4.0, 1.0, 0.5)]})
    assert rows["a"]["MGN"]["position_mae_um"] == pytest.approx(0.4) and "poly2" not in rows["a"]
    assert winners(rows["a"]) == {"position_mae_um": "rom", "stress_mae_mpa": "MGN",
                                  "oled_objective_area_rel_error_pct_mean": "kriging"}
    assert winners(rows["b"])["position_mae_um"] == "MGN"
    text = task_table(rows, seeds={"a": 2})
    assert "(d) zero-shot" in text and text.count("Not measured yet.") == 2 and "(2 seed(s) of the MGN)" in text
    text = task_table(task_rows({"d.cg_thin": [_m(0.3, 2.0, 0.1, 0.05)], "d.cg_thick": [_m(0.3, 2.0, 0.1, 0.05)]}))
    assert "zero-shot (a parameter training held fixed): cg_thin" in text and ": cg_thick" in text
    with pytest.raises(ValueError, match="task must be one of"):
        task_rows({"e": []})


def test_cli_writes_the_table_and_names_a_missing_file(tmp_path):
    from experiments import tasks_table
    f = tmp_path / "m.json"
    f.write_text(json.dumps(_m(0.3, 2.0, 0.1, 0.05)))
    out = tmp_path / "t.md"
    assert tasks_table.main(["--task", f"a={f}", f"b={f},{f}", "--out", str(out)]) == 0
    text = out.read_text()
    assert text.count("Winner per metric") == 2 and "(2 seed(s) of the MGN)" in text
    with pytest.raises(ValueError, match="does not exist"):
        tasks_table.main(["--task", f"b={tmp_path / 'nope.json'}"])
