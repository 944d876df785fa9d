"""Design on the truth over a panel stack (pcmgn_jax/opt/truth_stack.py, issue 50 item 4): the solver's
gradient per box unit (a thickness [m], a log10 modulus [decade]) against central differences of its own
values on a tiny stack, the hook from ``optimize_stack`` / ``opt.run`` (SLSQP and the projected gradient over
a box of bounds only, a cheap stand-in for the solver), the refusals by name, and (slow) a 2-iteration SLSQP
on the real solver. One solver per process (``stack_truth`` caches its compilation): the gradient check's and
the slow run's share it (the same nominal stack and box)."""
from __future__ import annotations

import dataclasses
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from fixtures.helpers import synthetic_scene_trajectory
from pcmgn_jax.data.stack import STACK_FAMILIES, variant_layers
from pcmgn_jax.scene import default_scene

FAM = STACK_FAMILIES["stack_tiny"]
N_FRAMES = 8                                         # 32 µs: the ball touches the cover glass within the window
PARAMS = ("OCA1.thickness", "OLED.log10_youngs")     # a thickness and a log10 modulus


def _scene0():
    return dataclasses.replace(FAM.base(default_scene()), n_frames=N_FRAMES)


@pytest.fixture(scope="module")
def stack_run(tmp_path_factory):
    """A ``stack_tiny`` run folder (config.json, no checkpoint) over two synthetic stacks of 6 and 5 layers whose
    scenes hold N_FRAMES frames, recorded as made by the solver at ``stack_tiny`` (no solver run)."""
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.data.trajectory_io import write_trajectory
    root = tmp_path_factory.mktemp("truth_stack_run")
    for i, count in enumerate((6, 5)):
        row = FAM.sample(1, 30 + i, layer_counts=(count,))[0]
        params = dict(zip(FAM.names, map(float, row)))
        meta = {"scene_params": params, "family": "stack_tiny", "name": f"s{count}", "solver": {"preset": "stack_tiny"}}
        traj = synthetic_scene_trajectory(FAM.scene(_scene0(), params), meta)
        write_trajectory(traj, root / "data" / "train" / f"train_{i:04d}")
    run = root / "run"
    run.mkdir()
    TrainConfig.from_preset("stack_tiny", dataset_dir=str(root / "data"), n_train=2, n_val=0,
                            n_test=0).save_json(run / "config.json")
    return run


def test_the_solver_parameters_and_the_thin_stiff_corner_of_a_stack_box():
    from pcmgn_jax.opt.scenes import stack_box
    from pcmgn_jax.opt.truth_stack import solver_names, stiff_corner
    box = stack_box()
    assert box.dim == 12 and solver_names(box)[:4] == ("CG.thickness", "CG.youngs", "OCA1.thickness", "OCA1.youngs")
    c = stiff_corner(box)
    thick = np.array([n.endswith(".thickness") for n in box.names])
    assert np.all(c[thick] == box.low[thick]) and np.all(c[~thick] == box.high[~thick])
    ball = stack_box(search=("ball.radius", "ball.velocity"))
    assert stiff_corner(ball).tolist() == [ball.low[0], ball.high[1]]


@pytest.mark.slow  # 21-28 s on this CPU; the family FD check stays in the fast suite
def test_stack_truth_gradient_matches_central_differences_per_box_unit():
    """One design of a tiny 6-layer stack, float64: the exact derivative in a thickness [MPa/m] and in a log10
    modulus [MPa per decade: dF/dE * E ln 10] against central differences of the same solver's values (one
    compilation: the probes' values come from the same value-and-gradient call); the objective's interface
    (cache, trace, fingerprint, check) on the same solver."""
    from pcmgn_jax.opt.scenes import stack_box
    from pcmgn_jax.opt.truth_stack import StackSolverObjective
    box = stack_box(search=PARAMS)
    obj = StackSolverObjective(_scene0(), FAM, "stack_tiny", box)
    truth = obj.surrogate
    assert truth.names == ("OCA1.thickness", "OLED.youngs") and truth.gs.mesh.n_nodes > 0
    x = np.array([112e-6, math.log10(6.0e9)])
    f, g = obj.value_and_grad(x[None])
    assert f.shape == (1,) and g.shape == (1, 2) and f[0] > 0 and np.all(np.isfinite(g)) and np.all(g != 0)
    assert obj(x[None])[0] == f[0] and obj.n_solver_runs == 1                   # the cache: no second run
    for k, h in enumerate((1e-8, 1e-4)):                                       # 0.01 µm; 1e-4 decade
        e = np.zeros(2)
        e[k] = h
        fd = (truth.value_and_grad(x + e)[0] - truth.value_and_grad(x - e)[0]) / (2 * h) * 1e-6
        assert fd == pytest.approx(g[0, k], rel=2e-3), (k, fd, g[0, k])
    rec = obj.trace[0]
    assert rec["design"] == {"OCA1.thickness": 112e-6, "OLED.log10_youngs": x[1]} and rec["wall_s"] > 0
    assert rec["grad_mpa"]["OLED.log10_youngs"] == g[0, 1] and len(obj.fingerprint()) == 16
    chk = obj.check(x)
    assert chk["n_substeps_per_frame"] == truth.gs.n_sub and chk["dt_s"] == obj.dt
    assert set(chk["step_set_at"]) == {"nominal", "thin_stiff_corner"} and isinstance(chk["same_run"], bool)


class _Quadratic:
    """A stand-in for :class:`StackTruth` (no solver): a bowl in box units with its minimum inside the box."""

    name, batch, setup_seconds = "solver", 1, 0.0

    def __init__(self, scene0, family, preset, box, reading):
        self.box, self.family, self.scene0 = box, family, scene0
        self.nominal = np.array([box.base[n] for n in box.names], float)
        self.corner = box.low.copy()
        self.target = box.low + 0.3 * (box.high - box.low)
        self.gs = SimpleNamespace(dt=1e-9, n_sub=7, n_frames=N_FRAMES, output_dt=4e-6, element="q4i", dtype="float64")
        self.calls = 0

    def scene(self, x):
        return self.box.design(np.asarray(x, float), self.family).scene(self.scene0)

    def _z(self, x):
        return (np.asarray(x, float) - self.target) / (self.box.high - self.box.low)

    def value(self, x):
        self.calls += 1
        return 1e6 * (1.0 + float(np.sum(self._z(x) ** 2)))

    def value_and_grad(self, x):
        return self.value(x), 1e6 * 2 * self._z(x) / (self.box.high - self.box.low)

    def host_check(self, x):
        return {"host_substeps_per_frame": 7, "pinned_layer_elems": {}, "host_layer_elems": {}, "same_mesh": True}


@pytest.fixture
def quadratic(monkeypatch):
    from pcmgn_jax.opt import truth_stack
    monkeypatch.setattr(truth_stack, "StackTruth", _Quadratic)
    monkeypatch.setattr(truth_stack, "_SOLVERS", {})


@pytest.mark.parametrize("method, iters", [("slsqp", 30), ("gradient", 40)])
def test_the_solver_search_of_a_stack_is_reached_from_the_pipeline(stack_run, quadratic, method, iters):
    """``opt.run`` on a stack run with the surrogate 'solver' reaches the stack's solver search: all 12 box
    numbers searched (SLSQP with no constraint but the bounds), the optimum of the stand-in found, the result
    written with its trace, check and the nominal stack's value and gradient; the resume file is removed."""
    from pcmgn_jax.opt import run
    from pcmgn_jax.opt.scenes import stack_box
    out = run(stack_run, surrogate="solver", method=method, starts=1, iters=iters, progress=False)
    box = stack_box()
    assert list(out["searched"]) == list(box.names) and out["surrogate"] == "solver" and out["method"] == method
    target = box.low + 0.3 * (box.high - box.low)
    got = np.array([out["optimum"][n] for n in box.names])
    assert np.all(np.abs(got - target) <= 0.02 * (box.high - box.low)), (got - target) / (box.high - box.low)
    assert out["predicted_mpa"] == out["solver_mpa"] == pytest.approx(1.0, abs=1e-3) and out["rel_error_pct"] == 0.0
    assert out["n_evals"] == len(out["trace"]) == out["solver_runs"] >= 2
    assert out["solver_check"]["same_run"] and "host_mpa" not in out["solver_check"]
    assert out["nominal_mpa"] > out["predicted_mpa"] and set(out["nominal_grad_mpa"]) == set(box.names)
    assert out["budget"] == {"starts": 1, "iters": iters} and out["spread"]["std_mpa"] == 0.0
    assert all(set(p["x"]) == set(box.names) for path in out["history"] for p in path)
    saved = json.loads((stack_run / "optimize" / f"solver_{method}.json").read_text())
    assert saved["optimum"] == pytest.approx(out["optimum"]) and saved["trace"] == out["trace"]
    assert not (stack_run / "optimize" / f"solver_{method}.resume.json").exists()


def test_a_killed_stack_solver_search_resumes_from_its_file_and_the_command_prints_it(stack_run, quadratic,
                                                                                      monkeypatch, capsys):
    """Killed after its search, the stack's solver search leaves its resume file (every evaluation with its
    trace); the same search again replays them (no solver run of the search) and writes the same optimum; the
    command prints the solver line (runs, dt, the host's run)."""
    from experiments import optimize
    from pcmgn_jax.opt import run, stack_search
    kw = {"surrogate": "solver", "method": "slsqp", "starts": 1, "iters": 6, "progress": False,
          "params": ("OCA1.thickness", "CG.log10_youngs", "OLED.log10_youngs")}

    def killed(*a, **k):
        raise KeyboardInterrupt
    with monkeypatch.context() as m:
        m.setattr(stack_search, "_dataset_best", killed)
        with pytest.raises(KeyboardInterrupt):
            run(stack_run, **kw)
    resume = next((stack_run / "optimize").glob("solver_slsqp_p*.resume.json"))
    saved = json.loads(resume.read_text())
    assert saved["n_evals"] == len(saved["trace"]) >= 2 and saved["meta"]["params"] == list(kw["params"])
    out = run(stack_run, **kw)
    assert out["resumed"] == {"evals_loaded": saved["n_evals"]} and out["solver_runs"] == 0
    assert out["trace"] == saved["trace"] and not resume.exists()
    capsys.readouterr()
    assert optimize.main(["--workdir", str(stack_run), "--surrogate", "solver", "--method", "slsqp", "--starts", "1",
                          "--iters", "6", "--params", ",".join(kw["params"]), "--no_progress"]) == 0
    printed = capsys.readouterr().out
    assert "solver slsqp on the stack CG/OCA1/POL/OCA2/OLED/PLATE" in printed and "solver: " in printed
    assert "substeps per frame); the host solver's own run at the optimum: the same" in printed, printed


def test_a_stack_search_refuses_a_method_that_does_not_fit_its_surrogate_by_name(stack_run):
    from pcmgn_jax.errors import SettingError
    from pcmgn_jax.opt import run
    from pcmgn_jax.opt.stack_search import optimize_stack
    kw = dict(objective="area_mean", pop=4, gens=1, seed=0, which="best", check=True, progress=False,
              preset="stack_tiny")
    with pytest.raises(SettingError, match=r"^method: 'ga' with the surrogate 'solver'.*use 'slsqp' or 'gradient'"):
        optimize_stack(stack_run, None, [], surrogate="solver", method="ga", **kw)
    with pytest.raises(ValueError, match="surrogate='solver' with method='ga'"):
        run(stack_run, surrogate="solver", method="ga", progress=False)
    with pytest.raises(SettingError, match=r"^method: 'slsqp': a stack search has no gradient on a surrogate.*"
                                           r"the surrogate 'solver' for 'slsqp'"):
        optimize_stack(stack_run, None, [], surrogate="kriging", method="slsqp", **kw)
    with pytest.raises(ValueError, match=r"'OLED.youngs' \(unknown\)"):   # the box names the modulus log10_youngs
        run(stack_run, surrogate="solver", method="slsqp", progress=False, params=("OLED.youngs",))


@pytest.mark.slow   # ~60 s: compiles the stack_tiny solver's value and gradient, one host solver run
def test_slsqp_on_the_solver_of_a_stack_end_to_end(stack_run):
    """A 2-iteration SLSQP over a thickness and a log10 modulus on the real solver through ``opt.run``: every
    evaluation a solver run in the trace, the optimum inside the box, the step recorded."""
    from pcmgn_jax.opt import run
    from pcmgn_jax.opt.pipeline import result_tag
    out = run(stack_run, surrogate="solver", method="slsqp", starts=1, iters=2, progress=False,
              stack=variant_layers(True, None), params=PARAMS)
    lo, hi = np.array(list(out["searched"].values())).T
    x = np.array([out["optimum"][n] for n in PARAMS])
    assert np.all((lo <= x) & (x <= hi)) and out["n_evals"] == len(out["trace"]) >= 2
    assert out["predicted_mpa"] in [e["mpa"] for e in out["trace"]] and out["nominal_mpa"] > 0
    chk = out["solver_check"]
    assert chk["dt_s"] > 0 and chk["n_substeps_per_frame"] >= 1 and ("host_mpa" in chk) != chk["same_run"]
    assert (stack_run / "optimize" / f"{result_tag('solver', 'slsqp', 'area_mean', (), PARAMS)}.json").exists()
