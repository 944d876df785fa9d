"""Design optimisation: objective readings, the design box, the design->mesh map, GA and gradient search,
the MGN's exact gradient, and the CLI end to end (the solver re-check on the tiny preset)."""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from fixtures.helpers import tensor_grid
from pcmgn_jax import metrics
from pcmgn_jax.opt import search
from pcmgn_jax.opt.problem import DesignBox


def _rect_mesh(nx, ny, xs=None, ys=None):
    """A 4 mm x 1 mm grid of nx x ny cells, or the given node lines [m]."""
    return tensor_grid(np.linspace(0, 4e-3, nx + 1) if xs is None else xs,
                       np.linspace(0, 1e-3, ny + 1) if ys is None else ys)


def test_objective_readings_against_hand_computed_values():
    """A graded 1-row strip, part 1, x in [0, 4] mm, section x <= 3 mm; field s = x (linear)."""
    xs = np.array([0, 0.5, 1.0, 3.0, 4.0]) * 1e-3                # graded: 3 of 5 columns near the axis
    pts, cells = _rect_mesh(4, 1, xs=xs, ys=np.array([0, 1e-4]))
    part = np.ones(len(cells), int)
    node_part = np.ones(len(pts), int)
    vm = np.broadcast_to(pts[:, 0] * 1e12, (3, len(pts)))       # [Pa], constant in time: x in mm -> 1000 x MPa
    w = {r: metrics.objective_weights(pts, cells, part, node_part, part=1, reading=r) for r in metrics.OBJECTIVES}
    for r in ("area_mean", "node_mean", "disc_mean"):
        assert w[r].sum() == pytest.approx(1.0)
    f = {r: float(metrics.oled_objective(vm, w[r], reading=r)) for r in metrics.OBJECTIVES}
    # node mean over nodes with x < 3 mm: x = 0, 0.5, 1 (mm), twice each -> 0.5 mm -> 500 MPa
    assert f["node_mean"] == pytest.approx(500.0)
    # area mean of s = x over [0, 3] mm: 1.5 mm -> 1500 MPa (the linear field is integrated exactly)
    assert f["area_mean"] == pytest.approx(1500.0)
    # disc mean: int x * 2 pi x dx / int 2 pi x dx over [0, 3] = 2 mm -> 2000 MPa
    assert f["disc_mean"] == pytest.approx(2000.0)
    assert f["peak"] == pytest.approx(1000.0)                  # the section's largest node value (x = 1 mm)


def test_area_mean_is_mesh_independent_where_node_mean_is_not():
    """s = exp(-x / 1 mm) on a uniform and a graded mesh of the same strip: the area mean agrees (shape
    functions), the node mean does not (it weighs the fine zone by its node count)."""
    vals = {}
    for name, xs in (("uniform", np.linspace(0, 3e-3, 31)), ("graded", 3e-3 * np.linspace(0, 1, 31) ** 2)):
        pts, cells = _rect_mesh(len(xs) - 1, 1, xs=xs, ys=np.array([0, 1e-4]))
        vm = np.exp(-pts[:, 0] / 1e-3)[None] * 1e6
        vals[name] = {r: float(metrics.oled_objective(vm, metrics.objective_weights(
            pts, cells, np.ones(len(cells)), np.ones(len(pts)), part=1, reading=r, x_max=3.1e-3), reading=r))
            for r in ("area_mean", "node_mean")}
    exact = (1 - np.exp(-3)) / 3
    assert vals["uniform"]["area_mean"] == pytest.approx(exact, rel=2e-3)
    assert vals["graded"]["area_mean"] == pytest.approx(exact, rel=2e-3)
    assert abs(vals["graded"]["node_mean"] / vals["uniform"]["node_mean"] - 1) > 0.2


def test_objective_rejects_empty_sections_and_unknown_readings():
    pts, cells = _rect_mesh(2, 1)
    with pytest.raises(ValueError, match="no cell of part 5"):
        metrics.objective_weights(pts, cells, np.ones(2), np.ones(len(pts)), part=5)
    with pytest.raises(ValueError, match="reading must be one of"):
        metrics.objective_weights(pts, cells, np.ones(2), np.ones(len(pts)), part=1, reading="max")


def test_projection_is_the_nearest_feasible_point():
    box = DesignBox()
    rng = np.random.default_rng(0)
    d = rng.uniform(0, 250e-6, (40, 2))
    p = box.project(d)
    assert np.all(box.violation(p) <= 1e-15)
    cand = box.project(rng.uniform(40e-6, 160e-6, (4000, 2)))     # feasible points to compare against
    for x, px in zip(d, p):
        assert np.linalg.norm(x - px) <= np.linalg.norm(cand - x, axis=1).min() + 1e-12
    feas = box.starts(5)
    assert np.allclose(box.project(feas), feas)


def test_infeasible_box_is_refused():
    with pytest.raises(ValueError, match="no design satisfies"):
        DesignBox(sum_low=400e-6, sum_high=500e-6)


class _Quadratic:
    """f = |d - c|^2 scaled to O(1) with its exact gradient; c outside the sum band."""

    name, n_evals = "quadratic", 0
    c = np.array([120e-6, 140e-6])

    def __call__(self, d):
        d = np.atleast_2d(d)
        self.n_evals += len(d)
        return np.sum((d - self.c) ** 2, axis=1) * 1e10

    def value_and_grad(self, d):
        d = np.atleast_2d(d)
        return self(d), 2 * (d - self.c) * 1e10


def test_ga_and_gradient_find_the_constrained_optimum():
    """The optimum is the projection of c onto T1 + T2 <= 250 µm: (115, 135) µm."""
    box = DesignBox()
    g = search.gradient(_Quadratic(), box, progress=False)
    assert np.allclose(g["x"] * 1e6, [115, 135], atol=0.3)
    a = search.ga(_Quadratic(), box, pop=40, gens=30, progress=False)
    assert np.allclose(a["x"] * 1e6, [115, 135], atol=3.0) and box.violation(a["x"])[0] <= 1e-12
    assert a["n_evals"] <= 40 * 30 and len(a["history"]) == 30


def test_slsqp_finds_constrained_and_bound_optima_in_few_evaluations():
    """SLSQP with the exact gradient: the sum-band optimum (115, 135) µm, and with c beyond a bound and
    the band the corner (150, 100) µm, each from 2 starts in far fewer evaluations than the fixed-step
    descent needs."""
    box = DesignBox()
    q = _Quadratic()
    s = search.slsqp(q, box, starts=2, progress=False)
    assert np.allclose(s["x"] * 1e6, [115, 135], atol=0.05)
    assert box.violation(s["x"])[0] <= 1e-12 and len(s["paths"]) == 2
    g = search.gradient(_Quadratic(), box, starts=2, progress=False)
    assert s["n_evals"] < g["n_evals"]

    class _Corner(_Quadratic):
        c = np.array([170e-6, 110e-6])    # projection onto the box and the band: (150, 100) µm
    s = search.slsqp(_Corner(), box, starts=3, seed=1, progress=False)
    assert np.allclose(s["x"] * 1e6, [150, 100], atol=0.05) and box.violation(s["x"])[0] <= 1e-12
    assert all(p[0]["f"] >= p[-1]["f"] for p in s["paths"])
    # screening: 16 values first, one start from the best of them
    q = _Quadratic()
    s = search.slsqp(q, box, starts=1, screen=16, progress=False)
    assert np.allclose(s["x"] * 1e6, [115, 135], atol=0.05) and len(s["screened"]) == 16
    best = min(s["screened"], key=lambda p: p["f"])
    assert np.allclose(s["paths"][0][0]["x_um"], best["x_um"]) and s["n_evals"] == q.n_evals


def test_design_map_is_the_mesh_builder_at_any_design():
    from pcmgn_jax.scene import default_scene
    from pcmgn_jax.sim.design_map import DesignMap, design_mesh
    scene = default_scene()
    dm = DesignMap.build(scene, "tiny")
    for d in ([60e-6, 140e-6], [150e-6, 50e-6]):
        assert np.abs(dm.points(np.array(d)) - design_mesh(scene, d, "tiny").points).max() < 1e-15
    import jax.numpy as jnp
    assert np.allclose(np.asarray(dm.points(jnp.asarray([60e-6, 140e-6]))), dm.points(np.array([60e-6, 140e-6])),
                       atol=1e-9)


def test_field_objective_caches_and_differentiates():
    from pcmgn_jax.opt.objectives import FieldObjective
    pts, cells = _rect_mesh(4, 2)
    mesh = SimpleNamespace(cells=cells, cell_part=np.ones(len(cells), int), node_part=np.ones(len(pts), int))
    dmap = SimpleNamespace(mesh=mesh, points=lambda d: pts)

    class Lin:  # von Mises = (a . d) * 1e12 everywhere: objective a . d * 1e6 [MPa]
        name, objective_surface = "lin", False
        calls = 0

        def predict(self, d):
            self.calls += 1
            s = (d @ np.array([2.0, -1.0])) * 1e12
            return None, np.broadcast_to(s[:, None, None], (len(d), 3, len(pts)))

    lin = Lin()
    obj = FieldObjective(lin, dmap, part=1)
    d = np.array([[100e-6, 80e-6], [100e-6, 80e-6], [90e-6, 70e-6]])
    f = obj(d)
    assert f == pytest.approx((d @ [2.0, -1.0]) * 1e6) and obj.n_evals == 2 and lin.calls == 1
    obj(d)
    assert lin.calls == 1                                          # cached
    _, g = obj.value_and_grad(d[:1])
    assert g[0] == pytest.approx([2e6, -1e6], rel=1e-6)


class _Bowl:
    """A fields surrogate whose objective is a bowl around (120, 140) µm [MPa]; ``fail_after`` calls of
    predict it raises KeyboardInterrupt (a kill)."""

    name, batch, objective_surface = "bowl", 7, False

    def __init__(self, n_nodes, fail_after=None):
        self.n, self.fail_after, self.calls, self.designs, self.x = n_nodes, fail_after, 0, 0, np.zeros(2)

    def predict(self, d):
        self.calls += 1
        if self.fail_after is not None and self.calls > self.fail_after:
            raise KeyboardInterrupt
        self.designs += len(d)
        s = (np.sum((d - [120e-6, 140e-6]) ** 2, axis=1) * 1e10 + 1.0) * 1e6
        return None, np.broadcast_to(s[:, None, None], (len(d), 3, self.n))


def _fitted_surface(kind, trajs, reading="area_mean"):
    import warnings

    from pcmgn_jax.surrogates.registry import fit_objective
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit_objective(kind, trajs, readings=(reading,), part=1)


def test_a_response_surface_is_read_at_designs_and_cached(tiny_trajs):
    """FieldObjective over a response surface (the optimiser's kriging / mop): each new row reaches the surrogate as
    a data.family.Design of the design layers (predict_objective_at, no fields), the values are the surface's own
    at those rows (what the optimiser read before the surfaces answered Designs), cached per design and
    differentiated by central differences; a reading the surface was not fitted for is refused by name."""
    from pcmgn_jax.data.family import Design
    from pcmgn_jax.opt.objectives import FieldObjective
    from pcmgn_jax.surrogates.kinds import CannotAnswer
    s = _fitted_surface("kriging", tiny_trajs)
    seen = []
    answer = s.predict_objective_at
    s.predict_objective_at = lambda designs, **kw: (seen.append(list(designs)), answer(designs, **kw))[1]
    obj = FieldObjective(s, SimpleNamespace(mesh=None, points=None), part=1, names=("CG",))
    d = np.array([[95e-6], [95e-6], [110e-6]])                    # tiny_trajs: one design layer, CG
    f = obj(d)
    assert f == pytest.approx(s.objective.predict(d[[0, 2]])["area_mean"][[0, 0, 1]], rel=0, abs=0)
    assert obj.n_evals == 2 and len(seen) == 1
    assert seen[0] == [Design(None, (("CG", 95e-6),)), Design(None, (("CG", 110e-6),))]
    obj(d)
    assert len(seen) == 1                                          # cached
    assert np.isfinite(obj.value_and_grad(d[:1])[1]).all() and len(obj.fingerprint()) == 16
    with pytest.raises(CannotAnswer, match="kriging: cannot answer the objective reading 'peak'"):
        FieldObjective(s, None, part=1, names=("CG",), reading="peak")(d)


def test_the_spread_of_an_optimum_at_its_design(tiny_trajs):
    """opt.spread at an optimum: kriging's own posterior std at the optimum's Design, the values its surface
    gives at that row; MOP (no std of its own) the kriging std of the same data, named as a proxy."""
    from pcmgn_jax.opt.objectives import FieldObjective
    from pcmgn_jax.opt.spread import optimum_spread
    x = np.array([105e-6])
    krig = _fitted_surface("kriging", tiny_trajs)
    want = krig.objective.predict(x[None], return_std=True)[1]["area_mean"][0]
    for kind in ("kriging", "mop"):
        obj = FieldObjective(_fitted_surface(kind, tiny_trajs), None, part=1, names=("CG",))
        got = optimum_spread(kind, obj, x, tiny_trajs, part=1, reading="area_mean")
        assert got["std_mpa"] == want and got["std_mpa"] > 0
        assert got["source"] == ("kriging posterior std" if kind == "kriging" else
                                 "proxy: the kriging std of the same training data (mop has no spread of its own)")


def test_the_solver_check_takes_a_design_of_the_design_layers():
    """opt.check.solver_objectives asks for a Design of the scene's design layers; another design is refused by
    name before any solver run."""
    from pcmgn_jax.data.family import Design
    from pcmgn_jax.opt.check import solver_objectives
    from pcmgn_jax.scene import default_scene
    with pytest.raises(ValueError, match=r"design layers \['OCA1', 'OCA2'\] \(no family\).*got OCA1=100 µm$"):
        solver_objectives(default_scene(), Design.of(None, [100e-6], ("OCA1",)), "tiny")


def test_ga_resumes_after_a_kill_with_the_same_result(tmp_path):
    """persist(): a GA killed part way, run again with the same seed, replays the stored values and ends
    exactly where an unbroken run does, evaluating only what the first run had not; a resume file of
    another search is refused, naming what differs."""
    from pcmgn_jax.opt.objectives import FieldObjective
    pts, cells = _rect_mesh(4, 2)
    mesh = SimpleNamespace(cells=cells, cell_part=np.ones(len(cells), int), node_part=np.ones(len(pts), int))
    dmap = SimpleNamespace(mesh=mesh, points=lambda d: pts)
    box, meta = DesignBox(), {"method": "ga", "pop": 20, "gens": 6, "seed": 3}

    whole = FieldObjective(_Bowl(len(pts)), dmap, part=1)
    ref = search.ga(whole, box, pop=20, gens=6, seed=3, progress=False)

    store = tmp_path / "bowl_ga.resume.json"
    first = FieldObjective(_Bowl(len(pts), fail_after=9), dmap, part=1)
    assert first.persist(store, meta) == 0
    with pytest.raises(KeyboardInterrupt):
        search.ga(first, box, pop=20, gens=6, seed=3, progress=False)
    saved = json.loads(store.read_text())
    done = first.surrogate.designs                                        # every finished batch, none lost
    assert saved["n_evals"] == len(saved["values"]) == done and 0 < done < ref["n_evals"]

    again = FieldObjective(_Bowl(len(pts)), dmap, part=1)
    assert again.persist(store, meta) == done and again.prior_seconds > 0
    res = search.ga(again, box, pop=20, gens=6, seed=3, progress=False)
    assert np.array_equal(res["x"], ref["x"]) and res["f"] == ref["f"] and res["history"] == ref["history"]
    assert res["n_evals"] == ref["n_evals"] == whole.n_evals
    assert again.surrogate.designs == ref["n_evals"] - done              # only the designs not stored
    with pytest.raises(ValueError, match=r"bowl_ga.resume.json: written for another search \(seed: 3 here 4\)"):
        FieldObjective(_Bowl(len(pts)), dmap, part=1).persist(store, {**meta, "seed": 4})


@pytest.mark.slow  # ~11 s (the default suite's 10-minute budget)
def test_mgn_objective_gradient_matches_finite_differences(tiny_run, tiny_trajs):
    """Exact forward-mode gradient of (design -> mesh -> rollout -> objective) on the tiny synthetic run
    (design: the CG thickness; the CG top and the ball move with it) against central differences."""
    from pcmgn_jax.opt.objectives import MGNObjective
    from pcmgn_jax.sim.design_map import DesignMap
    from pcmgn_jax.surrogates.mgn import MGNSurrogate
    _, workdir, _ = tiny_run
    ref = tiny_trajs[1]
    jac = np.zeros((1,) + ref.points.shape)
    jac[0, :, 1] = ref.points[:, 1] >= 400e-6 + 1e-9                # CG top row and the ball shift with t_cg
    mesh = SimpleNamespace(cells=ref.cells, cell_part=ref.cell_part, node_part=ref.node_part)
    t0 = ref.meta["design"]["CG"]
    dmap = DesignMap(mesh=mesh, d0=np.array([t0]), p0=ref.points, jac=jac)
    obj = MGNObjective(MGNSurrogate(workdir, ref), dmap, part=1, reading="area_mean")
    d = np.array([[t0]])
    f, g = obj.value_and_grad(d)
    # a barely trained model's rollout is rough at the µm scale (contact edges switch), so the check is
    # local: 0.1 µm steps (float32 noise in f ~1e-6 relative is ~1e-4 of the difference measured here)
    h = 1e-7
    fp, fm = obj(d + h), obj(d - h)
    assert np.isfinite(g).all() and f[0] == pytest.approx(obj(d)[0], rel=1e-4)
    assert abs(g[0, 0]) > 0
    assert g[0, 0] == pytest.approx((fp[0] - fm[0]) / (2 * h), rel=0.15)


@pytest.mark.slow
def test_optimize_cli_end_to_end_on_the_tiny_preset(tmp_path):
    """Generate a tiny dataset, fit poly2, GA + gradient, solver re-check, JSON and PNG."""
    from experiments import generate, optimize
    data = tmp_path / "data"
    assert generate.main(["--out", str(data), "--preset", "tiny", "--n_train", "7", "--n_val", "1",
                          "--n_test", "1", "--no_progress"]) == 0
    run = tmp_path / "run"
    run.mkdir()
    from pcmgn_jax.config import TrainConfig
    cfg = TrainConfig.from_preset("tiny", dataset_dir=str(data), n_train=7, n_val=1, n_test=1)
    (run / "config.json").write_text(json.dumps(cfg.to_dict()))
    for method in ("ga", "gradient", "slsqp"):
        budget = ["--pop", "12", "--gens", "4"] if method == "ga" else ["--starts", "4"]   # the method's own flags
        assert optimize.main(["--workdir", str(run), "--surrogate", "poly2", "--method", method, *budget,
                              "--grid", "5", "--no_progress"]) == 0
        out = json.loads((run / "optimize" / f"poly2_{method}.json").read_text())
        assert DesignBox().violation(np.array(out["optimum_um"]) * 1e-6)[0] <= 1e-12
        assert out["solver_mpa"] > 0 and np.isfinite(out["rel_error_pct"])
        assert out["predicted_std_mpa"] > 0 and out["spread"]["source"].startswith("proxy")   # never without ±
        assert (run / "optimize" / f"poly2_{method}.png").stat().st_size > 1000
        assert not (run / "optimize" / f"poly2_{method}.resume.json").exists()   # removed with the result
    # a kriging response surface of the objective itself (what a DOE tool optimises)
    assert optimize.main(["--workdir", str(run), "--surrogate", "kriging", "--method", "gradient", "--grid", "0",
                          "--no_progress"]) == 0
    out = json.loads((run / "optimize" / "kriging_gradient.json").read_text())
    assert DesignBox().violation(np.array(out["optimum_um"]) * 1e-6)[0] <= 1e-12 and np.isfinite(out["rel_error_pct"])
    assert out["spread"]["source"] == "kriging posterior std" and out["predicted_std_mpa"] >= 0
    # the second re-check of the same optimum comes from the cache
    assert len(list((run / "optimize" / "solver").glob("*.json"))) <= 3
    # auto: MOP's choice, with every candidate's CoP in the result
    assert optimize.main(["--workdir", str(run), "--surrogate", "auto", "--method", "gradient", "--grid", "0",
                          "--no_progress"]) == 0
    out = json.loads((run / "optimize" / "auto_gradient.json").read_text())
    cop = out["cop"][out["objective"]]
    assert cop["chosen"] in cop["cop"] and out["spread"]["source"].startswith("proxy")


def test_optimize_table_orders_by_the_solver_and_names_bad_files(tmp_path):
    from experiments import optimize_table
    base = {"objective": "area_mean", "dataset_best": {"design_um": [110.0, 135.0], "mpa": 1.01},
            "n_evals": 10, "search_seconds": 2.0, "command": "python -m experiments.optimize ..."}
    (tmp_path / "a.json").write_text(json.dumps({**base, "surrogate": "mgn", "method": "ga",
                                                 "budget": {"pop": 100, "gens": 50},
                                                 "optimum_um": [120, 94], "predicted_mpa": 0.97, "solver_mpa": 1.02,
                                                 "rel_error_pct": 4.9, "beats_dataset_best": False,
                                                 "surrogate_fingerprint": "0123456789abcdef"}))
    (tmp_path / "b.json").write_text(json.dumps({**base, "surrogate": "poly2", "method": "slsqp",
                                                 "budget": {"starts": 1, "iters": 20, "screen": 8},
                                                 "optimum_um": [150, 100], "predicted_mpa": 0.978, "solver_mpa": 0.98,
                                                 "rel_error_pct": 0.2, "beats_dataset_best": True}))
    out = tmp_path / "t.md"
    assert optimize_table.main(["--files", str(tmp_path / "*.json"), "--out", str(out)]) == 0
    table = [r for r in out.read_text().splitlines() if r.startswith("| `")]
    assert table[0].startswith("| `b.json` | poly2 | slsqp | 1 start × 20, 8 screened | 150.0 / 100.0 |")
    assert table[1].startswith("| `a.json` | mgn `01234567` | ga | 100 × 50 (paper) |") and table[1].endswith("| no |")
    assert "1.0100 MPa at 110.0 / 135.0 µm" in out.read_text()
    (tmp_path / "older").mkdir()       # another model's results under the same file name stay apart
    (tmp_path / "older" / "a.json").write_text((tmp_path / "a.json").read_text().replace("1.02", "1.05")
                                               .replace('"mpa": 1.01', '"mpa": 1.0100004'))  # last bits
    assert optimize_table.main(["--files", f"{tmp_path / '*.json'},{tmp_path / 'older' / '*.json'}",
                                "--out", str(out)]) == 0
    names = [r.split(" | ")[0] for r in out.read_text().splitlines() if r.startswith("| `")]
    assert names == ["| `b.json`", "| `a.json`", "| `older/a.json`"]
    assert "1.0100 MPa at 110.0 / 135.0 µm" in out.read_text()   # the same dataset best at the table's precision
    (tmp_path / "c.json").write_text("{}")
    with pytest.raises(ValueError, match="c.json: not a result of experiments.optimize"):
        optimize_table.main(["--files", str(tmp_path / "*.json")])
    (tmp_path / "c.json").write_text(json.dumps({"method": "ga", "optimum": {"OCA1.thickness": 1e-4},
                                                 "predicted_mpa": 1.0}))      # a stack search's result
    with pytest.raises(ValueError, match="c.json: a stack search's result"):
        optimize_table.main(["--files", str(tmp_path / "*.json")])
