"""The explorer and ``experiments.optimize`` on a panel-stack run (issue 40): a slider per padded scene
parameter, the baselines that cannot answer a stack refused by name, the stack search over a named subset
(a clear error for an unknown name), and (slow) the run's MGN in both.

The run: six synthetic ``stack_tiny`` stacks of 5 and 7 layers on their real meshes (no solver;
tests/fixtures/helpers.py ``synthetic_stack``) written as an imported dataset, and a ``stack_tiny`` config
over them, made once per module (~2 s).
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from fixtures.helpers import synthetic_stack
from pcmgn_jax.data.stack import STACK_FAMILIES, nominal, value_ranges, variant_layers

FAM = STACK_FAMILIES["stack_tiny"]


@pytest.fixture(scope="module")
def stack_run(tmp_path_factory):
    """A run directory (config.json, no checkpoint) over six synthetic stacks: 5, 7, 5, 7, 5, 7 layers."""
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.data.trajectory_io import write_trajectory
    root = tmp_path_factory.mktemp("stack_run")
    for i, count in enumerate((5, 7, 5, 7, 5, 7)):
        write_trajectory(synthetic_stack(count, 20 + i, solver=True), root / "data" / "train" / f"train_{i:04d}")
    run = root / "run"
    run.mkdir()
    TrainConfig.from_preset("stack_tiny", dataset_dir=str(root / "data"), n_train=6, n_val=0,
                            n_test=0).save_json(run / "config.json")
    return run


@pytest.fixture(scope="module")
def stack_explorer(stack_run):
    from pcmgn_jax.explore import Explorer
    return Explorer(stack_run, mgn=False, kinds=("none", "nearest", "poly2", "kriging", "mop"), log=lambda s: None)


def test_a_slider_per_stack_parameter_in_the_family_order(stack_explorer):
    ex = stack_explorer
    assert ex.names == FAM.names and len(ex.params) == len(FAM.names) == 26
    by = {p.name: p for p in ex.params}
    assert (by["OCA1.thickness"].unit, by["OCA1.thickness"].scale, by["OCA1.thickness"].label) == \
        ("µm", 1e6, "OCA1 thickness")
    assert (by["CG.log10_youngs"].unit, by["CG.log10_youngs"].label) == ("log10 Pa", "CG modulus")
    assert by["TSP.present"].label == "TSP present (1/0)" and by["ball.radius"].unit == "mm"
    # the box: the family's ranges (an imported dataset has no manifest); a fixed layer's flag is not varied
    fam_box = {n: (lo, hi) for n, lo, hi in FAM.parameters}
    assert all(np.allclose((p.low, p.high), fam_box[p.name]) for p in ex.params)
    assert not by["CG.present"].varied and by["POL.present"].varied
    # the page opens at the paper's six layers, nominal; its scene has them
    assert dict(zip(ex.names, ex.start)) == pytest.approx(nominal())
    assert [layer.name for layer in ex.scene_at(ex.start).layers] == list(variant_layers(True, None))


def test_the_explorer_takes_a_design(stack_explorer):
    """A Design of the family is what the explorer's methods take as well as the sliders' values: the same
    canonical row, scene, query and (cached) predictions; a Design lacking a parameter is refused by name."""
    from pcmgn_jax.data.family import Design
    ex = stack_explorer
    d = ex.design(ex.start)
    assert isinstance(d, Design) and d.family is FAM and d.names == FAM.names
    assert ex.design(ex.values(d)) == d and ex.design(d) == d       # its canonical row: an absent film's thickness 0
    assert ex.query(d).meta["scene_params"] == ex.query(ex.start).meta["scene_params"] == d.row
    shuffled = Design(FAM, tuple(reversed(d.params)))                 # names in another order: the same design
    assert ex.query(shuffled) is ex.query(d)
    assert ex.predict(shuffled, ["kriging"])["kriging"].objective_mpa == \
        ex.predict(ex.start, ["kriging"])["kriging"].objective_mpa
    assert [layer.name for layer in ex.scene_at(shuffled).layers] == list(variant_layers(True, None))
    with pytest.raises(ValueError, match=r"no value for \['ball.velocity'\]"):
        ex.flags(Design(FAM, tuple(p for p in d.params if p[0] != "ball.velocity")))


def test_the_stack_explorer_refuses_by_name_and_answers_what_it_can(stack_explorer):
    ex = stack_explorer
    assert "one shared topology" in ex.skipped["poly2"]          # per-node regression: one mesh only
    flags = ex.flags(ex.start)
    assert any("6 layers" in f and "never trained on" in f for f in flags), flags
    rows = {r["name"]: r for r in ex.view(ex.start).rows}
    assert rows["nearest"]["mpa"] is None and "no training scene has the parts" in rows["nearest"]["text"]
    assert np.isfinite(rows["kriging"]["mpa"]) and rows["kriging"]["std"] > 0
    # switch the polarizer off: a 5-layer stack, whose layer list training has: the nearest scene answers
    five = ex.start.copy()
    five[ex.names.index("POL.present")] = 0.0
    q = ex.query(five)
    assert "POL" not in q.meta["part_names"] and q.meta["scene_params"]["POL.thickness"] == 0.0
    assert not any("never trained on" in f for f in ex.flags(five))
    rows = {r["name"]: r for r in ex.view(five).rows}
    assert np.isfinite(rows["nearest"]["mpa"]) and np.isfinite(rows["kriging"]["mpa"])
    # both extra films on: 8 layers, outside the family; a thickness outside its range: named
    odd = ex.start.copy()
    odd[ex.names.index("TSP.present")] = odd[ex.names.index("BF.present")] = 1.0
    odd[ex.names.index("CG.thickness")] = 300e-6
    flags = ex.flags(odd)
    assert any("8 layers, outside the family's 5 to 7" in f for f in flags), flags
    assert any(f.startswith("stack range: this design: CG.thickness") for f in flags), flags
    # an absent layer's sliders are not part of the design: nothing is flagged for them
    absent = ex.start.copy()
    absent[ex.names.index("TSP.thickness")] = 500e-6
    assert not any("TSP" in f for f in ex.flags(absent)) and any("TSP" in f for f in ex.flags(
        np.where(np.array(ex.names) == "TSP.present", 1.0, absent)))
    # a present layer of thickness 0 is a clear error (the page shows it and keeps the previous design)
    bad = ex.start.copy()
    bad[ex.names.index("POL.thickness")] = 0.0
    with pytest.raises(ValueError, match="layer POL is present with thickness 0.0"):
        ex.query(bad)


def test_stack_box_searches_a_named_subset_and_names_what_it_cannot():
    from pcmgn_jax.opt.scenes import stack_box
    box = stack_box()
    assert box.names == tuple(f"{n}.{w}" for n in variant_layers(True, None) for w in ("thickness", "log10_youngs"))
    assert np.allclose(box.low[0], 60e-6) and np.allclose(box.high[0], 140e-6)       # CG: 100 µm +-40 %
    sub = stack_box(("CG", "OCA1", "TSP", "OCA2", "OLED", "PLATE"), ("TSP.thickness", "ball.radius"))
    assert sub.names == ("TSP.thickness", "ball.radius")
    assert np.allclose([sub.low, sub.high], np.array([value_ranges()[n] for n in sub.names]).T)
    row = sub.row([40e-6, 5e-3])
    assert row["TSP.thickness"] == 40e-6 and row["POL.present"] == 0.0 and row["POL.thickness"] == 0.0
    assert row["OCA1.thickness"] == pytest.approx(100e-6)                                # held at nominal
    with pytest.raises(ValueError, match=r"'foo' \(unknown\).*Searchable for this stack: CG.thickness"):
        stack_box(search=("OCA1.thickness", "foo"))
    with pytest.raises(ValueError, match=r"'BF.thickness' \(layer BF is not in the stack"):
        stack_box(search=("BF.thickness",))
    with pytest.raises(ValueError, match="a presence flag"):
        stack_box(search=("POL.present",))
    with pytest.raises(ValueError, match="no stack of the family"):
        stack_box(("CG", "OCA1", "OCA2", "PLATE"))                 # no OLED


def test_the_stack_search_finds_a_known_optimum():
    """A fake objective surface with its minimum at OCA2 = 120 µm, OLED modulus 10^9.5 Pa: the GA over those
    two names finds it, the rest of the row stays nominal."""
    from types import SimpleNamespace

    from pcmgn_jax.opt import search
    from pcmgn_jax.opt.scenes import stack_box
    from pcmgn_jax.opt.stack_search import StackObjective

    seen = []

    def predict_objective_at(designs, *, reading):   # what the optimiser asks: Designs of the family [SI]
        seen.extend(designs)
        r = {n: np.array([d.row[n] for d in designs]) for n in designs[0].names}
        return ((r["OCA2.thickness"] - 120e-6) / 40e-6) ** 2 + ((r["OLED.log10_youngs"] - 9.5) / 0.3) ** 2 + 1.0

    surface = SimpleNamespace(objective_surface=True, predict_objective_at=predict_objective_at,
                              objective=SimpleNamespace(scenes=SimpleNamespace(x=np.zeros((1, len(FAM.names))))))
    box = stack_box(search=("OCA2.thickness", "OLED.log10_youngs"))
    obj = StackObjective("kriging", surface, box, scene0=None, family=FAM, ref=None, preset="stack_tiny", part=-1)
    res = search.ga(obj, box, pop=30, gens=25, seed=0, progress=False)
    assert res["x"] == pytest.approx([120e-6, 9.5], rel=0.02) and res["f"] == pytest.approx(1.0, abs=0.01)
    # every candidate reached the surrogate as a Design of the family: the box's full row, canonical
    assert seen and all(d.family is FAM and d.row == box.row([d.row[n] for n in box.names]) for d in seen)
    assert obj.designs(res["x"])[0].row == box.row(res["x"]) and len(seen) == obj.n_evals
    with pytest.raises(ValueError, match="no gradient"):
        obj.value_and_grad(res["x"][None])


def test_optimize_searches_a_stack_run(stack_run):
    from pcmgn_jax.opt import run
    layers = ("CG", "OCA1", "OCA2", "OLED", "PLATE")          # a 5-layer stack: training has its layer list
    out = run(stack_run, surrogate="kriging", method="ga", pop=6, gens=2, check=False, progress=False,
              stack=layers, params=("OCA1.thickness", "ball.velocity"))
    from pcmgn_jax.opt.pipeline import result_tag
    tag = result_tag("kriging", "ga", "area_mean", layers, ("OCA1.thickness", "ball.velocity"))   # named by its search
    assert tag.startswith("kriging_ga_CG-OCA1-OCA2-OLED-PLATE_p")
    saved = json.loads((stack_run / "optimize" / f"{tag}.json").read_text())
    assert saved["optimum"] == pytest.approx(out["optimum"]) and saved["stack"] == list(layers)
    assert list(saved["searched"]) == ["OCA1.thickness", "ball.velocity"]
    base = nominal(list(layers))
    held = {n: v for n, v in saved["optimum"].items() if n not in saved["searched"] and n.endswith("thickness")
            and saved["optimum"][n.replace("thickness", "present")]}
    assert held == pytest.approx({n: base[n] for n in held})
    assert saved["predicted_std_mpa"] > 0 and saved["spread"]["source"] == "kriging posterior std"
    assert not (stack_run / "optimize" / f"{tag}.resume.json").exists()


def test_optimize_refuses_what_cannot_answer_a_stack_by_name(stack_run):
    from pcmgn_jax.opt import run
    layers = ("CG", "OCA1", "OCA2", "OLED", "PLATE")
    assert run(stack_run, surrogate="nearest", method="ga", pop=4, gens=1, check=False, progress=False,
               stack=layers)["n_evals"] >= 1
    with pytest.raises(ValueError, match=r"nearest cannot answer a stack of \['CG', 'OCA1', 'POL', 'OCA2', 'OLED', "
                                         r"'PLATE'\] here: nearest scene: no training scene has the parts"):
        run(stack_run, surrogate="nearest", method="ga", pop=4, gens=1, check=False, progress=False)
    with pytest.raises(ValueError, match=r"rbf cannot answer .* rbf: per-node regression needs one shared topology .*"
                                         r"here the meshes differ"):
        run(stack_run, surrogate="rbf", method="ga", pop=4, gens=1, check=False, progress=False)
    with pytest.raises(ValueError, match="method: 'gradient': a stack search has no gradient"):
        run(stack_run, surrogate="kriging", method="gradient", check=False, progress=False)
    with pytest.raises(ValueError, match=r"'OLED.thikness' \(unknown\)"):
        run(stack_run, surrogate="kriging", method="ga", check=False, progress=False, params=("OLED.thikness",))


@pytest.mark.slow   # ~40 s: a 20-step stack_tiny model, its rollouts, one stack_tiny solver run
def test_the_stack_runs_mgn_in_the_explorer_and_the_optimiser(stack_run, tmp_path):
    import shutil

    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.data.splits import load_splits
    from pcmgn_jax.explore import Explorer
    from pcmgn_jax.opt import run
    from pcmgn_jax.train import loop as training
    run_dir = tmp_path / "run"
    shutil.copytree(stack_run, run_dir, ignore=shutil.ignore_patterns("optimize"))
    cfg = TrainConfig.load(run_dir / "config.json").replace(num_steps=20, val_every=20, ckpt_every=20)
    train, _, _ = load_splits(cfg.resolved_dataset_dir, n_train=6, n_val=0, n_test=0)
    training.train(cfg, run_dir, train_trajs=train[:5], val_trajs=train[5:])
    ex = Explorer(run_dir, kinds=("kriging",), log=lambda s: None)
    assert ex.default == "mgn"
    p = ex.predict(ex.start, ["mgn"])["mgn"]                   # a 6-layer stack: a count never trained on
    assert np.isfinite(p.objective_mpa) and p.vm.shape == (ex.ref.n_frames, ex.query(ex.start).n_nodes)
    truth = ex.check(ex.start)                                  # the solver on the stack of the sliders
    assert np.isfinite(truth.objective_mpa) and truth.traj.meta["part_names"] == ex.query(ex.start).meta["part_names"]
    out = run(run_dir, surrogate="mgn", method="ga", pop=4, gens=1, check=True, progress=False,
              params=("OCA1.thickness",))
    assert np.isfinite(out["predicted_mpa"]) and np.isfinite(out["solver_mpa"]) and "proxy" in out["spread"]["source"]


def test_slider_headings_name_a_unit_only_where_there_is_one():
    from pcmgn_jax.explore.types import parameter
    assert parameter("CG.present", 1.0, 1.0).heading == "CG present (1/0)"
    assert parameter("CG.thickness", 6e-5, 1.4e-4).heading == "CG thickness [µm]"
    assert parameter("ball.radius", 4e-3, 6e-3).heading == "ball radius [mm]"


@pytest.mark.parametrize("layers, why", [
    ("CG,OLED", "2 layers; the family's stacks have 5 to 7"),
    ("CG,OCA1,POL,TSP,OCA2,OLED,BF,PLATE", "8 layers"),
    ("OCA1,POL,OCA2,OLED,PLATE", "without CG"),
    ("CG,OCA1,POL,OCA2,PLATE", "without OLED"),
    ("CG,OCA1,TSP,OCA2,OLED,BF,PLATE", "at most one extra film"),
])
def test_a_stack_search_outside_the_family_is_refused_before_the_search(stack_run, layers, why):
    """Issue 52: a layer list the family never holds (it used to exit 0 with a prediction 99 % off) is refused
    by name before the search; nothing is written."""
    from pcmgn_jax.opt import run
    before = sorted(p.name for p in (stack_run / "optimize").glob("*")) if (stack_run / "optimize").exists() else []
    with pytest.raises(ValueError, match=f"are no stack of the family \\({why}"):
        run(stack_run, surrogate="kriging", method="ga", pop=4, gens=1, check=False, progress=False,
            stack=layers.split(","))
    after = sorted(p.name for p in (stack_run / "optimize").glob("*")) if (stack_run / "optimize").exists() else []
    assert after == before


def test_stack_searches_are_named_by_their_search_and_a_replacement_is_said(stack_run, capsys):
    from pcmgn_jax.opt import run
    from pcmgn_jax.opt.pipeline import result_tag
    kw = dict(surrogate="kriging", method="ga", pop=4, gens=1, check=False, progress=False)
    six = run(stack_run, **kw)                     # the paper's six: a layer list no training stack has
    assert "no training stack of this run has the layers CG,OCA1,POL,OCA2,OLED,PLATE" in six["warnings"][0]
    five = ("CG", "OCA1", "OCA2", "OLED", "PLATE")
    run(stack_run, **kw, stack=five)
    names = {p.name for p in (stack_run / "optimize").glob("kriging_ga*.json")}
    assert {"kriging_ga.json", f"{result_tag('kriging', 'ga', 'area_mean', five)}.json"} <= names
    capsys.readouterr()
    run(stack_run, **{**kw, "seed": 1})
    out = capsys.readouterr().out
    assert "note: replacing" in out and "kriging_ga.json" in out and "differs in seed" in out, out


def test_optimize_takes_typed_lists_and_the_command_line_splits_its_comma_strings(tmp_path, monkeypatch):
    """pcmgn_jax.opt.run takes sequences of names (a comma string is a TypeError naming the argument);
    experiments.optimize parses --stack / --params / --ensemble into them."""
    from experiments import optimize
    from pcmgn_jax.opt import pipeline, run
    with pytest.raises(TypeError, match="stack='CG,OLED': give a sequence of names"):
        run(tmp_path, surrogate="kriging", stack="CG,OLED")
    seen = {}
    monkeypatch.setattr(pipeline, "_optimize", lambda workdir, **kw: seen.update(kw) or {})
    monkeypatch.setattr(pipeline, "hold", lambda *a: __import__("contextlib").nullcontext())
    import pcmgn_jax.mgn.checkpoint as checkpoint
    monkeypatch.setattr(checkpoint, "require_run", lambda *a, **k: None)
    with pytest.raises(KeyError):   # the fake result has no optimum to print: the call itself is what is checked
        optimize.main([f"--workdir={tmp_path}", "--surrogate=mgn", "--stack= CG,OLED ", "--params=a.b",
                       "--ensemble=r1,r2"])
    assert seen["stack"] == ("CG", "OLED") and seen["params"] == ("a.b",) and seen["ensemble"] == ("r1", "r2")
    assert pipeline.result_tag("kriging", "ga", "area_mean", ("CG", "OLED")) == "kriging_ga_CG-OLED"
