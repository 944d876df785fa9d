"""The study runner's bookkeeping (experiments/study.py, pcmgn_jax/studies/), without training:
cells.run_cell is replaced by a recorder that returns made-up metrics, so these tests check the settings
each cell trains with and the tables written after every cell, not any model."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from experiments import study
from fixtures.helpers import ROOT
from pcmgn_jax import cli
from pcmgn_jax.studies import ablation, cells, paper as studies


@pytest.fixture(autouse=True)
def _no_persistent_cache(monkeypatch):
    """study.main turns on JAX's persistent compilation cache for its process; not in the test process."""
    monkeypatch.setattr(cells, "use_compilation_cache", lambda folder, min_compile_seconds=1.0: None)


@pytest.mark.slow  # ~6 s (the default suite's 10-minute budget)
def test_compilation_cache_is_written_and_read(tmp_path):
    """In a fresh process, a compiled function lands in the folder; a second process loads it (JAX's
    cache-hit event)."""
    code = ("import sys, jax, jax.numpy as jnp\n"
            "from pcmgn_jax.studies import cells\n"
            "jax.monitoring.register_event_listener(lambda name, **kw: print('event', name, file=sys.stderr))\n"
            "cells.use_compilation_cache(sys.argv[1], min_compile_seconds=0)\n"
            "f = jax.jit(lambda x: jnp.sin(x) @ x.T + 1.0)\n"
            "print(float(f(jnp.ones((64, 64))).sum()))\n")
    runs = [subprocess.run([sys.executable, "-c", code, str(tmp_path / "c")], capture_output=True, text=True,
                           cwd=str(ROOT)) for _ in range(2)]
    for r in runs:
        assert r.returncode == 0, r.stderr
    assert runs[0].stdout == runs[1].stdout
    assert "/jax/compilation_cache/cache_hits" not in runs[0].stderr
    assert "/jax/compilation_cache/cache_hits" in runs[1].stderr
    files = sorted(p.name for p in (tmp_path / "c").rglob("*") if p.is_file())
    assert files, "nothing was written to the compilation cache"


def _fake_metrics(pos: float) -> dict:
    return {"position_mae_um": pos, "stress_mae_mpa": 2 * pos, "oled_objective_area_rel_error_pct_mean": 3.0,
            "penetration_max_um": 0.1, "train_seconds": 1.0, "per_frame_position_mae_um_mean": [pos, pos],
            "baselines": {"none": {"position_mae_um": 10.0, "stress_mae_mpa": 30.0,
                                   "oled_objective_area_rel_error_pct_mean": 100.0, "penetration_max_um": 0.0}}}


@pytest.mark.slow  # ~11 s (the default suite's 10-minute budget); test_study's cell-config tests stay
def test_degree_study_flags_and_table(tmp_path, monkeypatch):
    calls = []

    def fake(workdir, settings, extra_data=None):
        calls.append((str(workdir), dict(settings)))
        return _fake_metrics(settings["poly_ball"] / 10 + len(calls) * 1e-3)

    monkeypatch.setattr(cells, "run_cell", fake)
    assert study.main(["--name", "degree", "--seeds", "0", "--runs", str(tmp_path / "runs"),
                       "--out", str(tmp_path / "out")]) == 0
    n_cells = len(studies.STUDIES["degree"][2])
    assert len(calls) == 2 * n_cells                       # both formulations, one seed
    paper = [f for w, f in calls if "/paper/" in w]
    default = [f for w, f in calls if "/default/" in w]
    # the paper's formulation keeps its own lambda = 10; the default gets lambda = 10 only in this study
    assert all(f["lambda_pen"] == 10 and f["formulation"] == "paper" for f in paper)
    assert all(f["lambda_pen"] == 10 and f["formulation"] == "default" for f in default)
    # the cell's own settings come last, so they win over the base settings
    assert all(list(f)[-2:] == ["poly_ball", "poly_panel"] for _, f in calls)
    md = (tmp_path / "out" / "degree.md").read_text()
    assert "Partial" not in md and "not run yet" not in md
    assert "--lambda_pen=10" in md                         # the table says what the default formulation added
    assert "- paper: best cell by position MAE **B.2/P.3** (paper: B.6/P.5, not the same)" in md
    assert (tmp_path / "out" / "degree_per_frame.png").stat().st_size > 0
    res = json.loads((tmp_path / "out" / "degree.json").read_text())["results"]
    assert set(res) == {"paper", "default"} and len(res["paper"]) == n_cells


def test_study_cut_short_leaves_a_partial_table(tmp_path, monkeypatch):
    n = {"calls": 0}

    def fake(workdir, settings, extra_data=None):
        n["calls"] += 1
        if n["calls"] == 3:
            raise KeyboardInterrupt                         # the session is cut during the third cell
        return _fake_metrics(1.0)

    monkeypatch.setattr(cells, "run_cell", fake)
    with pytest.raises(KeyboardInterrupt):
        study.main(["--name", "noise_parts", "--formulations", "paper", "--runs", str(tmp_path / "runs"),
                    "--out", str(tmp_path / "out")])
    md = (tmp_path / "out" / "noise_parts.md").read_text()
    assert "Partial: 2 of 8 cell-seeds measured" in md
    rows = [r for r in md.splitlines() if r.startswith("| paper |")]
    assert len(rows) == 4
    assert rows[0].startswith("| paper | none | 1 ± 0 |")                 # both seeds of "none" done
    assert all("not run yet" in r for r in rows[1:])


def test_unknown_study_is_refused():
    with pytest.raises(ValueError, match="--name must be one of"):
        study.main(["--name", "nope"])


def test_same_training_cells_are_not_retrained(tmp_path, monkeypatch):
    """noise_parts in the default formulation: panel = none and all = ball (SAME_AS), so 2 of its 4
    cells train; the table says which cell each one repeats and why."""
    calls = []

    def fake(workdir, settings, extra_data=None):
        calls.append(settings["noise_parts"])
        return _fake_metrics(1.0 if calls[-1] == "none" else 2.0)

    monkeypatch.setattr(cells, "run_cell", fake)
    assert study.main(["--name", "noise_parts", "--formulations", "default", "--seeds", "0",
                       "--runs", str(tmp_path / "runs"), "--out", str(tmp_path / "out")]) == 0
    assert calls == ["none", "ball"]
    md = (tmp_path / "out" / "noise_parts.md").read_text()
    assert "Partial" not in md
    row = next(r for r in md.splitlines() if r.startswith("| default | panel"))
    assert "(= none, not retrained" in row and "| 1 |" in row
    row = next(r for r in md.splitlines() if r.startswith("| default | all"))
    assert "(= ball, not retrained" in row and "| 2 |" in row


def test_orderings_against_the_paper():
    """Kendall's tau is +1 when the cells rank as the paper's do and -1 when reversed; the best cells."""
    table = studies.STUDIES["noise_sigma"][2]
    same = {"paper": {c[0]: {"0": {"position_mae_um": c[2][0] * 5, "stress_mae_mpa": c[2][1] + 3}} for c in table}}
    line = studies.ordering_lines(same, ["paper"], table)[0]
    assert "**0.3 µm** (paper: 0.3 µm, the same)" in line
    assert "over 4 cells, Kendall's tau: position +1.00, stress +1.00" in line
    rev = {"default": {c[0]: {"0": {"position_mae_um": -c[2][0], "stress_mae_mpa": -c[2][1]}} for c in table}}
    line = studies.ordering_lines(rev, ["paper", "default"], table)
    assert len(line) == 1 and "position -1.00, stress -1.00" in line[0] and "not the same" in line[0]
    # the extrapolation study has no paper numbers: best cell only
    ext = studies.STUDIES["extrapolation"][2]
    res = {"default": {c[0]: {"0": {"position_mae_um": i, "stress_mae_mpa": i}} for i, c in enumerate(ext)}}
    assert studies.ordering_lines(res, ["default"], ext) == [f"- default: best cell by position MAE **{ext[0][0]}**"]


def test_render_rewrites_the_table_from_its_json_without_running_cells(tmp_path, monkeypatch):
    monkeypatch.setattr(cells, "run_cell", lambda workdir, settings, extra_data=None: _fake_metrics(1.5))
    args = ["--name", "target", "--seeds", "0", "--runs", str(tmp_path / "runs"), "--out", str(tmp_path / "out")]
    assert study.main(args) == 0
    src = tmp_path / "out" / "target.json"       # a note kept in the JSON (as the older tables carry)
    src.write_text(json.dumps(dict(json.loads(src.read_text()), note="made before X")))
    assert study.main(args + ["--render"]) == 0
    md = (tmp_path / "out" / "target.md").read_text()
    assert "> made before X" in md and json.loads(src.read_text())["note"] == "made before X"
    (tmp_path / "out" / "target.md").unlink()

    def refuse(*a, **k):
        raise AssertionError("render must not run a cell")
    monkeypatch.setattr(cells, "run_cell", refuse)
    assert study.main(args + ["--render"]) == 0
    assert (tmp_path / "out" / "target.md").read_text() == md
    assert json.loads(src.read_text())["note"] == "made before X"     # a second render keeps it too
    with pytest.raises(FileNotFoundError, match="no study results to render"):
        study.main(["--name", "degree", "--render", "--out", str(tmp_path / "nothing")])


@pytest.mark.slow  # ~8 s (the default suite's 10-minute budget)
def test_rerunning_one_formulation_keeps_the_others_rows(tmp_path, monkeypatch):
    """``--formulations default`` after a full run re-measures the default rows only: the paper rows and
    the command that measured them survive; a re-run at other steps is refused, naming the file."""
    value = {"v": 1.0}
    calls = []

    def fake(workdir, settings, extra_data=None):
        calls.append(str(workdir))
        return _fake_metrics(value["v"])

    monkeypatch.setattr(cells, "run_cell", fake)
    common = ["--name", "target", "--seeds", "0", "--runs", str(tmp_path / "runs"), "--out", str(tmp_path / "out")]
    assert study.main(common) == 0
    value["v"], calls[:] = 5.0, []
    assert study.main(common + ["--formulations", "default", "--runs", str(tmp_path / "runs2")]) == 0
    assert calls and all("/default/" in w for w in calls)
    d = json.loads((tmp_path / "out" / "target.json").read_text())
    assert list(d["results"]) == ["paper", "default"]
    assert all(s["0"]["position_mae_um"] == 1.0 for s in d["results"]["paper"].values())
    assert all(s["0"]["position_mae_um"] == 5.0 for s in d["results"]["default"].values())
    assert d["kept"] == {"paper": "python -m experiments.study " + " ".join(common)}
    md = (tmp_path / "out" / "target.md").read_text()
    assert "The `paper` rows are kept from an earlier run" in md
    assert [r.split(" | ")[2] for r in md.splitlines() if r.startswith("| paper |")] == ["1"] * 3
    assert [r.split(" | ")[2] for r in md.splitlines() if r.startswith("| default |")] == ["5"] * 3
    with pytest.raises(ValueError, match="target.json: its \\['paper'\\] rows were measured at 1500 steps"):
        study.main(common + ["--formulations", "default", "--num_steps", "7"])


def test_a_cell_scored_on_an_earlier_checkpoint_says_so(tmp_path, monkeypatch):
    """The evaluation uses the best checkpoint by validation; when that is not the last step (e.g. a
    penalty that starts half-way only made validation worse) the row names the step."""
    def fake(workdir, settings, extra_data=None):
        late = settings["lambda_pen"] == 0
        return {**_fake_metrics(1.0), "checkpoint_step": 1000 if late else 500}

    monkeypatch.setattr(cells, "run_cell", fake)
    assert study.main(["--name", "lambda", "--formulations", "default", "--runs", str(tmp_path / "runs"),
                       "--out", str(tmp_path / "out")]) == 0
    rows = [r for r in (tmp_path / "out" / "lambda.md").read_text().splitlines() if r.startswith("| default |")]
    assert rows[0].startswith("| default | none (0) | ")
    assert all(r.startswith(f"| default | {c} (best checkpoint: step 500, 500 of 1000) |")
               for r, c in zip(rows[1:], ("0.1", "1", "10", "30")))


def test_a_cell_trained_with_other_settings_is_refused(tmp_path):
    """cells.run_cell finds a cell by its directory; a directory trained with other values of the settings
    asked for (e.g. a study's base settings edited since) is refused, naming the field, not reused."""
    wd = tmp_path / "cell"
    wd.mkdir()
    cells.config_of({"preset": "cpu", "lambda_pen": 10.0}).save_json(wd / "config.json")
    cells.check_settings(wd, {"preset": "cpu", "lambda_pen": 10.0})             # the same: fine
    with pytest.raises(ValueError, match=r"config.json: this cell was trained with lambda_start=0.5 but is "
                                         r"asked for lambda_start=0.0; move .* away"):
        cells.run_cell(wd, {"preset": "cpu", "lambda_pen": 10.0, "lambda_start": 0.0})


@pytest.mark.slow  # ~7 s (the default suite's 10-minute budget)
def test_lambda_study_starts_the_paper_formulations_penalty_at_step_0(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(cells, "run_cell", lambda wd, settings, extra_data=None: calls.append((str(wd), settings))
                        or _fake_metrics(1.0))
    assert study.main(["--name", "lambda", "--seeds", "0", "--runs", str(tmp_path / "runs"),
                       "--out", str(tmp_path / "out")]) == 0
    assert all((f.get("lambda_start") == 0) == ("/paper/" in w) for w, f in calls)
    text = (tmp_path / "out" / "lambda.md").read_text()
    assert "The `paper` formulation adds `--lambda_start=0` in this study." in text


def test_cell_settings_are_the_training_flags_they_are_written_as():
    """Every study and ablation cell's config is the one ``python -m experiments.train`` builds from the
    flags the tables and records write for it (cells.as_flags), and floats are written unpadded."""
    for name, (_, _, table) in studies.STUDIES.items():
        for form in studies.BASE:
            for _, settings, _, _ in table:
                s = studies.cell_settings(name, form, settings, data="data/cpu", steps=7, seed=1)
                assert cli.parse_config([*cells.as_flags(s), "--no_progress"]) == cells.config_of(s), (name, form)
    for name in ablation.CELLS:
        s = ablation.cell_settings(name, 2, 5)
        assert cli.parse_config([*cells.as_flags(s), "--no_progress"]) == cells.config_of(s), name
    assert cells.as_flags(studies.BASE["paper"]) == ["--formulation=paper", "--noise_std=3e-7", "--noise_rel=0",
                                                   "--noise_parts=all", "--lambda_pen=10"]
    assert cells.as_flags({"rigid_ball": True, "contact_projection": False, "scene_features": ()}) == \
        ["--rigid_ball", "--no_contact_projection", "--scene_features=none"]


def test_run_cell_trains_once_resumes_a_killed_training_and_evaluates(tmp_path, monkeypatch):
    """run_cell trains the settings' config (no progress bar) with pcmgn_jax.train.run, scores it with
    pcmgn_jax.eval.run, never retrains a finished cell, resumes from the saved config when a periodic
    checkpoint exists, and evaluates each extra directory once."""
    import pcmgn_jax.eval as evaluation
    import pcmgn_jax.eval.evaluate as evaluate_mod
    import pcmgn_jax.train as training
    trained, scored = [], []

    def fake_train(cfg, workdir, *, resume=False):
        trained.append((cfg, resume))
        cfg.save_json(workdir / "config.json")
        return {"step": 7, "seconds": 1.0, "best_val": 2.0}

    def fake_eval(workdir, *, which="best", data="", name="", contact_projection=""):
        scored.append((data, name))
        out = workdir / "eval" / name if name else workdir / "eval"
        out.mkdir(parents=True, exist_ok=True)
        (out / "metrics.json").write_text(json.dumps({"position_mae_um": 1.0}))
        return {"position_mae_um": 1.0}

    monkeypatch.setattr(training, "run", fake_train)
    monkeypatch.setattr(evaluation, "run", fake_eval)
    monkeypatch.setattr(evaluate_mod, "summary_table", lambda m: "table")
    monkeypatch.setattr(cells, "checkpoint_step", lambda workdir: 7)
    wd = tmp_path / "cell"
    wd.mkdir()
    settings = {"preset": "tiny", "num_steps": 7, "seed": 3}
    m = cells.run_cell(wd, settings)
    assert trained == [(cells.config_of(settings), False)] and not trained[0][0].progress
    assert m["position_mae_um"] == 1.0 and m["checkpoint_step"] == 7 and m["train_seconds"] >= 0
    assert cells.run_cell(wd, settings, extra_data={"x": "dirx"})["eval_x"] == {"position_mae_um": 1.0}
    assert len(trained) == 1 and scored == [("", ""), ("dirx", "x")]
    (wd / "eval" / "metrics.json").unlink()                # a killed training: periodic checkpoints, no eval
    (wd / "checkpoints" / "periodic").mkdir(parents=True)
    cells.run_cell(wd, settings)
    assert trained[-1] == (cells.config_of(settings), True)
