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
    assert "(d) zero-shot" in text and text.count("Not measured yet.") == 3 and "(2 seed(s) of the MGN)" in text
    text = task_table(task_rows({"d.cg_thin": [_m(0.3, 2.0, 0.1, 0.05)], "d.cg_thick": [_m(0.3, 2.0, 0.1, 0.05)]}))
    assert "zero-shot (a parameter training held fixed): cg_thin" in text and ": cg_thick" in text
    with pytest.raises(ValueError, match="task must be one of"):
        task_rows({"f": []})


def test_cli_writes_the_table_and_names_a_missing_file(tmp_path):
    from experiments import tasks_table
    f = tmp_path / "m.json"
    f.write_text(json.dumps(_m(0.3, 2.0, 0.1, 0.05)))
    out = tmp_path / "t.md"
    assert tasks_table.main(["--task", f"a={f}", f"b={f},{f}", "--out", str(out)]) == 0
    text = out.read_text()
    assert text.count("Winner per metric") == 2 and "(2 seed(s) of the MGN)" in text
    assert "Code of the 3 metrics files: 3 from no code record (older files)." in text and "**At a glance**" in text
    with pytest.raises(ValueError, match="does not exist"):
        tasks_table.main(["--task", f"b={tmp_path / 'nope.json'}"])
    bad = tmp_path / "half.json"
    bad.write_text('{"position_mae_um": 0.3,')  # a file cut off mid-write
    with pytest.raises(ValueError, match="half.json is not JSON"):
        tasks_table.main(["--task", f"b={bad}"])


def test_summary_names_the_best_baseline_and_the_ratio():
    from pcmgn_jax.eval.tasks import summary_table
    rows = task_rows({"a": [_m(0.3, 2.0, 0.1, 0.05)]})
    text = summary_table(rows)
    best_pos = min(v["position_mae_um"] for n, v in rows["a"].items() if n != "MGN" and "position_mae_um" in v)
    name = next(n for n, v in rows["a"].items() if n != "MGN" and v.get("position_mae_um") == best_pos)
    assert "| a | " in text and f"0.3 / {best_pos:.3g} ({name}): {0.3 / best_pos:.2g}×" in text


def test_a_corrected_mgn_is_named_and_not_mixed_with_a_plain_one():
    from pcmgn_jax.eval.tasks import summary_table, task_table
    plain, fixed = _m(0.3, 2.0, 0.1, 0.05), {**_m(0.2, 1.0, 0.1, 0.05), "residual_of": "rom"}
    rows = task_rows({"b": [plain], "b.rom": [fixed, fixed]})
    assert "residual_of" not in rows["b"]["MGN"] and rows["b.rom"]["MGN"]["residual_of"] == "rom"
    text = task_table(rows)
    assert "the rom baseline corrected by the network" in text
    # every heading keeps its task letter, after a corrected variant too
    assert "### (b) scene family (family test split): rom" in text and "### (None)" not in text
    assert "| b.rom (MGN = rom + correction) |" in summary_table(rows)
    with pytest.raises(ValueError, match="mix"):
        task_rows({"b": [plain, fixed]})


def test_code_note_names_mixed_code_versions():
    from pcmgn_jax.eval.tasks import code_note
    a = {**_m(0.3, 2.0, 0.1, 0.05), "code": {"commit": "a" * 40, "dirty": False}}
    b = {**_m(0.3, 2.0, 0.1, 0.05), "code": {"commit": "b" * 40, "dirty": True}}
    assert code_note({"a": [a, a]}) == f"Code of the 2 metrics files: 2 from {'a' * 10}."
    mixed = code_note({"a": [a], "b": [b, _m(0.3, 2.0, 0.1, 0.05)]})
    assert "1 from bbbbbbbbbb (uncommitted changes)" in mixed and "no code record" in mixed
    assert mixed.endswith("made by different code: compare with care.")


def test_rows_carry_the_mgn_seed_range_into_the_table():
    rows = task_rows({"a": [_m(0.3, 2.0, 0.1, 0.05), _m(0.5, 4.0, 0.1, 0.05)]})
    assert rows["a"]["MGN"]["position_mae_um_seeds"] == [0.3, 0.5] and "position_mae_um_seeds" not in rows["a"]["rom"]
    assert "| 0.4 (0.3–0.5) |" in task_table(rows)


def test_learning_curve_crossings_table_plot_and_cli(tmp_path):
    from experiments import learning_curve as cli_curve
    from pcmgn_jax.eval.learning_curve import crossings, curve_rows, curve_table
    # the MGN's objective error falls 4.0 -> 1.0 -> 0.2 while kriging's stays 0.5: they cross at n = 48;
    # its position error never reaches rom's 0.1
    pts = {24: [_m(0.4, 1.0, 0.1, 0.5), _m(0.6, 1.0, 0.1, 0.5)], 8: [_m(0.9, 4.0, 0.1, 0.5)],
           48: [_m(0.2, 0.2, 0.1, 0.5)]}
    rows = curve_rows(pts)
    assert list(rows) == [8, 24, 48] and rows[24]["MGN"]["position_mae_um"] == pytest.approx(0.5)
    cross = crossings(rows)
    assert cross["oled_objective_area_rel_error_pct_mean"] == {"kriging": [48]}
    assert cross["position_mae_um"] == {"rom": []} and cross["stress_mae_mpa"] == {"rom": [8, 24, 48]}
    text = curve_table(rows)
    assert "| 24 | 0.5 (0.4–0.6) | – | 0.1 |" in text and "rom: never (n ≤ 48)" in text and "kriging: at n = 48" in text
    assert "rom: at n = 8, 24, 48 (every size)" in text
    with pytest.raises(ValueError, match="different test sets"):
        curve_rows({8: [{**_m(1, 1, 1, 1), "n_test": 8}], 16: [{**_m(1, 1, 1, 1), "n_test": 3}]})
    files = []
    for i, (n, ms) in enumerate(pts.items()):
        fs = [tmp_path / f"m{i}_{j}.json" for j in range(len(ms))]
        for f, m in zip(fs, ms):
            f.write_text(json.dumps(m))
        files.append(f"{n}=" + ",".join(map(str, fs)))
    out = tmp_path / "lc"
    assert cli_curve.main(["--point", *files, "--out", str(out)]) == 0
    rec = json.loads((out / "learning_curve.json").read_text())
    assert rec["crossings"]["oled_objective_area_rel_error_pct_mean"] == {"kriging": [48]}
    assert rec["files"]["24"] == files[0].partition("=")[2].split(",")
    assert (out / "learning_curve.png").stat().st_size > 1000 and (out / "learning_curve.md").exists()
    with pytest.raises(ValueError, match="whole number of solver runs"):
        cli_curve.main(["--point", f"many={tmp_path / 'm0_0.json'}", "--out", str(out)])


def test_manifest_drives_the_tables_and_the_reading_is_kept(tmp_path):
    from experiments import tasks_table
    f = tmp_path / "m.json"
    f.write_text(json.dumps(_m(0.3, 2.0, 0.1, 0.05)))
    man = tmp_path / "tasks.toml"
    man.write_text(f'[tasks]\na = ["{f}", "{f}"]\n"d.cg_thin" = ["{f}"]\n')
    out = tmp_path / "t.md"
    out.write_text(f"old tables\n{tasks_table.KEEP_MARKER}\n\n## Reading\nhand-written\n")
    assert tasks_table.main(["--manifest", str(man), "--out", str(out)]) == 0
    text = out.read_text()
    assert "old tables" not in text and text.count("Winner per metric") == 2 and "(2 seed(s) of the MGN)" in text
    assert text.endswith(f"{tasks_table.KEEP_MARKER}\n\n## Reading\nhand-written\n")
    assert "--manifest" in text.splitlines()[2]
    assert tasks_table.main(["--manifest", str(man), "--out", str(out)]) == 0 and out.read_text() == text
    man.write_text('[tasks]\na = "not a list"\n')
    with pytest.raises(ValueError, match="tasks.a must be a non-empty list"):
        tasks_table.main(["--manifest", str(man)])
    man.write_text("[tasks\n")
    with pytest.raises(ValueError, match="is not TOML"):
        tasks_table.main(["--manifest", str(man)])
    with pytest.raises(ValueError, match="does not exist"):
        tasks_table.main(["--manifest", str(tmp_path / "none.toml")])
    man.write_text(f'[tasks]\na = ["{f}"]\n')
    with pytest.raises(ValueError, match="given twice"):
        tasks_table.main(["--manifest", str(man), "--task", f"a={f}"])


def test_a_task_evaluated_without_baselines_borrows_them_within_its_test_split(tmp_path):
    """[baselines] lends a --no_baselines task the baselines of another evaluation of the same test split, checked
    by the test designs' true objectives; a table with no baselines says so instead of crowning the MGN."""
    from experiments import tasks_table
    from pcmgn_jax.eval.tasks import lend_baselines
    with_b = {**_m(0.3, 2.0, 0.1, 0.05), "oled_objective_area_true_mpa": [1.0, 1.2]}
    bare = {k: v for k, v in _m(0.2, 3.0, 0, 0).items() if k != "baselines"}
    bare["oled_objective_area_true_mpa"] = [1.0, 1.2]
    assert "No baselines in these files" in task_table(task_rows({"b.x": [bare]}))
    lent = lend_baselines([bare, with_b], with_b)
    assert lent[0]["baselines"] == with_b["baselines"] and lent[0]["position_mae_um"] == 0.2 and "baselines" not in bare
    other = {**bare, "oled_objective_area_true_mpa": [1.0, 1.3]}
    with pytest.raises(ValueError, match="src.json: its test split is not that of file 1"):
        lend_baselines([other], with_b, name="src.json")
    with pytest.raises(ValueError, match="no baselines and test truths to lend"):
        lend_baselines([bare], bare)
    fb, fs = tmp_path / "bare.json", tmp_path / "src.json"
    fb.write_text(json.dumps(bare))
    fs.write_text(json.dumps(with_b))
    man = tmp_path / "tasks.toml"
    man.write_text(f'[tasks]\n"b.x" = ["{fb}"]\n[baselines]\n"b.x" = "{fs}"\n')
    out = tmp_path / "t.md"
    assert tasks_table.main(["--manifest", str(man), "--out", str(out)]) == 0
    text = out.read_text()
    assert "| kriging |" in text and "Winner per metric" in text and "No baselines" not in text
    man.write_text(f'[tasks]\n"b.x" = ["{fb}"]\n[baselines]\n"b.y" = "{fs}"\n')
    with pytest.raises(ValueError, match="baselines.b.y names a task the \\[tasks\\] table lacks"):
        tasks_table.main(["--manifest", str(man)])
