"""Design on the truth (pcmgn_jax/opt/truth.py): the solver's exact gradient against central differences of the
same objective's values, SLSQP through ``pcmgn_jax.opt.run`` on a tiny run folder, the resume file replayed (no
new solver run) and refused for another search, and the command's refusals. One solver objective per process
(``truth_solver`` caches its compilation): the fixture's and the pipeline's share it."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from fixtures.helpers import synthetic_scene_trajectory
from pcmgn_jax.opt.problem import DesignBox
from pcmgn_jax.scene import Scene, default_scene

N_FRAMES = 12     # a short window: the solver's cost, not its compilation, scales with it


@pytest.fixture(scope="module")
def truth_run(tmp_path_factory):
    """(run folder, scene): config.json over three synthetic trajectories of the paper's panel on the ``tiny``
    ROI mesh, recorded as made by the solver at ``tiny`` (no solver run: the search's values are its own)."""
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.data.trajectory_io import write_trajectory
    root = tmp_path_factory.mktemp("truth_run")
    scene = dataclasses.replace(default_scene(), n_frames=N_FRAMES)
    for i, d in enumerate(((100e-6, 100e-6), (140e-6, 90e-6), (60e-6, 140e-6))):
        s = scene.with_design(*d)
        meta = {"design": dict(zip(s.design_layers, d)), "solver": {"preset": "tiny"}, "name": f"t{i}"}
        write_trajectory(synthetic_scene_trajectory(s, meta, preset="tiny"), root / "data" / "train" / f"train_{i:04d}")
    run = root / "run"
    run.mkdir()
    TrainConfig.from_preset("tiny", dataset_dir=str(root / "data"), n_train=3, n_val=0,
                            n_test=0).save_json(run / "config.json")
    return run, Scene.from_dict(scene.with_design(100e-6, 100e-6).to_dict())   # the pipeline's: its train[0]


@pytest.fixture(scope="module")
def truth(truth_run):
    from pcmgn_jax.opt.truth import SolverObjective
    _, scene = truth_run
    return SolverObjective(scene, "tiny", DesignBox(), part=scene.part_names.index("OLED"))


def test_extreme_designs_are_the_paper_box_vertices_and_projected_corners():
    from pcmgn_jax.opt.truth import extreme_designs
    got = {tuple(np.round(x * 1e6, 6)) for x in extreme_designs(DesignBox())}
    assert got == {(50, 100), (100, 50), (150, 50), (150, 100), (100, 150), (50, 150), (75, 75), (125, 125)}


@pytest.mark.slow  # ~26 s; the solver gradient's fast FD check is tests/sim/test_differentiable.py
def test_exact_gradient_matches_central_differences_of_the_same_values(truth):
    """Two designs' value and gradient in one call against central differences (0.01 µm) of the objective's
    values, each component within 1 % of the gradient's norm; the step is the box's, held fixed."""
    d = np.array([[120e-6, 80e-6], [95e-6, 130e-6]])
    f, g = truth.value_and_grad(d)
    assert f.shape == (2,) and g.shape == (2, 2) and np.all(f > 0) and np.all(np.isfinite(g))
    assert truth(d) == pytest.approx(f, rel=1e-12)                         # the cache: no second run
    h = 1e-8
    for k in range(2):
        e = np.zeros(2)
        e[k] = h
        fd = (truth(d + e) - truth(d - e)) / (2 * h)
        assert np.all(np.abs(fd - g[:, k]) <= 0.01 * np.linalg.norm(g, axis=1)), (k, fd, g[:, k])
    chk = truth.check(d[0])
    assert chk["same_run"] and chk["n_substeps_per_frame"] == chk["host_substeps_per_frame"]
    assert truth.trace[0]["grad_mpa_per_m"] is not None and truth.trace[-1]["grad_mpa_per_m"] is None


@pytest.mark.slow  # ~19 s: compiles the tiny solver's value and gradient
def test_slsqp_on_the_solver_end_to_end_resumes_and_refuses_another_search(truth_run, truth, monkeypatch):
    """A 2-iteration SLSQP through ``opt.run``: killed after its search (the resume file stays), refused for
    another budget (naming it), then run again: every evaluation replayed from the file, no solver run, the
    same result; the result holds the trace and its check is its own value."""
    import pcmgn_jax.opt.spread as spread
    from pcmgn_jax import opt
    run, _ = truth_run
    kw = {"surrogate": "solver", "method": "slsqp", "starts": 1, "iters": 2, "progress": False}

    def killed(*a, **k):
        raise KeyboardInterrupt
    with monkeypatch.context() as m:
        m.setattr(spread, "optimum_spread", killed)
        with pytest.raises(KeyboardInterrupt):
            opt.run(run, **kw)
    resume = run / "optimize" / "solver_slsqp.resume.json"
    saved = json.loads(resume.read_text())
    n = saved["n_evals"]
    assert n >= 2 and len(saved["trace"]) == n
    assert [e["seconds"] for e in saved["trace"]] == sorted(e["seconds"] for e in saved["trace"])
    with pytest.raises(ValueError, match=r"solver_slsqp.resume.json: written for another search \(iters: 2 here 3\)"):
        opt.run(run, **{**kw, "iters": 3})

    out = opt.run(run, **kw)
    assert out["resumed"] == {"evals_loaded": n} and out["solver_runs"] == 0 and out["n_evals"] == n
    assert out["trace"] == saved["trace"] and not resume.exists()
    assert DesignBox().violation(np.array(out["optimum_um"]) * 1e-6)[0] <= 1e-12
    assert out["solver_mpa"] == out["predicted_mpa"] in [e["mpa"] for e in out["trace"]]
    assert out["rel_error_pct"] == 0.0
    assert out["solver_check"]["same_run"] and out["predicted_std_mpa"] == 0.0 and "grid" not in out
    assert (run / "optimize" / "solver_slsqp.json").exists()


def test_the_command_refuses_the_ga_and_no_check_for_the_solver(truth_run):
    from experiments import optimize
    run, _ = truth_run
    with pytest.raises(ValueError, match="surrogate='solver' with method='ga'"):
        optimize.main(["--workdir", str(run), "--surrogate", "solver", "--method", "ga", "--no_progress"])
    with pytest.raises(ValueError, match="--check does not apply: --surrogate solver"):
        optimize.main(["--workdir", str(run), "--surrogate", "solver", "--method", "slsqp", "--no_check"])


def test_optimize_trace_draws_the_trace_against_the_ga_results(tmp_path):
    """A solver trace and a GA result: the best-so-far curve, the GA's line and point, the table with the
    evaluations and time after which the trace is within 0.5 % of the GA's solver-checked optimum."""
    from experiments import optimize_trace
    trace = [{"design_um": [100, 100], "mpa": 1.12, "seconds": 80.0}, {"design_um": [150, 50], "mpa": 1.09,
              "seconds": 160.0}, {"design_um": [150, 99], "mpa": 1.0712, "seconds": 250.0}]
    base = {"method": "slsqp", "optimum_um": [150.0, 99.0], "predicted_mpa": 1.0712, "solver_mpa": 1.0712,
            "n_evals": 3, "search_seconds": 250.0}
    (tmp_path / "solver_slsqp.json").write_text(json.dumps({**base, "surrogate": "solver", "trace": trace}))
    (tmp_path / "mgn_ga.json").write_text(json.dumps({**base, "surrogate": "mgn", "method": "ga", "solver_mpa": 1.0709,
                                                      "n_evals": 5000, "search_seconds": 900.0}))
    out = tmp_path / "trace"
    assert optimize_trace.main(["--files", str(tmp_path / "*.json"), "--train_seconds", "mgn_ga=3600",
                                "--out", str(out)]) == 0
    md = out.with_suffix(".md").read_text()
    assert "| `mgn_ga` | mgn | ga | 1.0709 | 150.0 / 99.0 | 5,000 | 900 | 3600 | 4500 |" in md
    assert "| `solver_slsqp` | `mgn_ga` 1.0709 | 3 | 250 |" in md
    assert out.with_suffix(".png").stat().st_size > 1000
    with pytest.raises(ValueError, match="--train_seconds 'kriging_ga=5': give NAME=S with NAME one of"):
        optimize_trace.main(["--files", str(tmp_path / "*.json"), "--train_seconds", "kriging_ga=5", "--out", str(out)])
