"""Gradients at a dataset's designs (pcmgn_jax.data.gradients): one record per design, written as it goes and
resumed after a kill, refused for another dataset's file, matched to designs by their rows, its cost in solves;
a stack row's from its own scene by the chain rule; the curve's kinds that refuse a size listed as such.
The differentiable solver is replaced by an analytic objective here (its own checks are tests/sim); the
slow test runs the real one on a family scene."""
from __future__ import annotations

import types

import numpy as np
import pytest

from fixtures.helpers import fake_scene_solve as _fake_solve
from pcmgn_jax.data import gradients as dg
from pcmgn_jax.data.dataset import ensure_dataset
from pcmgn_jax.data.layout import DatasetError
from pcmgn_jax.data.splits import split_designs

A = np.array([3.0e9, -1.0e9])    # the analytic objective's gradient [Pa/m]: f = 1 MPa + A . (t - 100 µm)


@pytest.fixture()
def fake_solver(monkeypatch):
    """dsim.setup / value_fn / value_and_grad_fn of the analytic objective; ``calls`` counts the setups."""
    from pcmgn_jax.sim import differentiable as dsim
    calls = []

    def setup(scenes, preset, *, names, reading):
        assert names == ["OCA1.thickness", "OCA2.thickness"] and reading == "area_mean"
        calls.append(scenes[0].design)
        return types.SimpleNamespace(theta=np.array([scenes[0].design]), dt=1e-8, n_sub=3)

    def value(theta):
        return 1e6 + (theta - 100e-6) @ A
    monkeypatch.setattr(dsim, "setup", setup)
    monkeypatch.setattr(dsim, "value_fn", lambda gs: value)
    monkeypatch.setattr(dsim, "value_and_grad_fn", lambda gs: lambda th: (value(th), np.tile(A, (len(th), 1))))
    return calls


@pytest.fixture()
def data(tmp_path):
    designs = np.array([[40e-6, 160e-6], [120e-6, 60e-6], [90e-6, 90e-6]])
    return ensure_dataset(tmp_path / "d", preset="tiny", designs=designs, split="train", solve_fn=_fake_solve,
                          progress=False)


def test_records_resume_and_refusals(fake_solver, data, tmp_path):
    out = tmp_path / "g.json"
    doc = dg.design_gradients(data, "train", n=2, out=out, time_every=2, progress=None)
    assert [r["index"] for r in doc["records"]] == [0, 1] and doc["names"] == ["OCA1", "OCA2"]
    r0 = doc["records"][0]
    assert r0["gradient"] == {"OCA1": 3.0e9, "OCA2": -1.0e9} and r0["row"] == {"OCA1": 40e-6, "OCA2": 160e-6}
    assert r0["objective_pa"] == pytest.approx(1e6 + (40e-6 - 100e-6) * 3e9 - (160e-6 - 100e-6) * 1e9)
    assert "wall_value_s" in r0 and "wall_value_s" not in doc["records"][1]      # every time_every-th
    # a rerun with more designs solves only the new one (a killed run resumes so)
    n_before = len(fake_solver)
    doc = dg.design_gradients(data, "train", n=3, out=out, progress=None)
    assert len(fake_solver) == n_before + 1 and [r["index"] for r in doc["records"]] == [0, 1, 2]
    assert dg.load_gradients(out)["records"] == doc["records"]
    with pytest.raises(DatasetError, match="another reading"):
        dg.design_gradients(data, "train", n=3, out=out, reading="peak", progress=None)
    with pytest.raises(DatasetError, match="holds 3 designs, 4 asked for"):
        dg.design_gradients(data, "train", n=4, out=tmp_path / "h.json", progress=None)


def test_aligned_by_row_and_cost_in_solves(fake_solver, data, tmp_path):
    doc = dg.design_gradients(data, "train", n=3, out=tmp_path / "g.json", time_every=1, progress=None)
    designs = split_designs(data, "train")
    got = dg.aligned_gradients(doc, [designs[2], designs[0]])
    assert set(got) == {"OCA1", "OCA2"} and got["OCA1"].shape == (2,)
    np.testing.assert_array_equal(got["OCA2"], [-1e9, -1e9])
    doc["records"] = doc["records"][1:]
    with pytest.raises(DatasetError, match="no gradient of the design OCA1=40 µm, OCA2=160 µm"):
        dg.aligned_gradients(doc, designs)
    for r, (vg, v) in zip(doc["records"], ((6.0, 1.0), (9.0, 2.0))):
        r["wall_value_and_grad_s"], r["wall_value_s"] = vg, v
    assert dg.cost_in_solves(doc) == pytest.approx(5.25)    # median of 6 and 4.5
    for r in doc["records"]:
        r.pop("wall_value_s")
    with pytest.raises(ValueError, match="no record timed the value alone"):
        dg.cost_in_solves(doc)


def test_row_parameters_map_to_solver_parameters():
    """A family row's layer name is its thickness, the ball's numbers themselves (factor 1); a stack row's
    thickness is its layer's, its log10 modulus the modulus times E ln 10, its flag and an absent slot's
    numbers 0 (None); a name that maps to nothing is refused by name."""
    from pcmgn_jax.scene import Scene
    scene = Scene()          # CG, OCA1, POL, OCA2, OLED, PLATE
    e_cg = scene.layers[0].youngs
    got = dg.solver_parameters(["OCA1", "ball.velocity", "CG.log10_youngs", "CG.thickness", "CG.present",
                                "TSP.thickness", "TSP.log10_youngs", "TSP.present"], scene)
    assert got == {"OCA1": ("OCA1.thickness", 1.0), "ball.velocity": ("ball.velocity", 1.0),
                   "CG.log10_youngs": ("CG.youngs", pytest.approx(e_cg * np.log(10))),
                   "CG.thickness": ("CG.thickness", 1.0), "CG.present": None, "TSP.thickness": None,
                   "TSP.log10_youngs": None, "TSP.present": None}
    assert dg.differentiated(got) == ["OCA1.thickness", "ball.velocity", "CG.youngs", "CG.thickness"]
    solver = {"OCA1.thickness": 2.0, "ball.velocity": 3.0, "CG.youngs": 5.0, "CG.thickness": 7.0}
    assert dg.row_gradient(got, solver) == {"OCA1": 2.0, "ball.velocity": 3.0, "CG.log10_youngs":
                                            pytest.approx(5.0 * e_cg * np.log(10)), "CG.thickness": 7.0,
                                            "CG.present": 0.0, "TSP.thickness": 0.0, "TSP.log10_youngs": 0.0,
                                            "TSP.present": 0.0}
    for bad in ("OCA1.poisson", "FOO.thickness", "ball.density", "POLX"):
        with pytest.raises(ValueError, match=f"row parameter '{bad}' has no solver parameter"):
            dg.solver_parameters([bad], scene)


def test_stack_rows_by_the_chain_rule(monkeypatch, tmp_path):
    """A stack dataset's designs (e2: 5 and 7 layers): each is differentiated in its own scene with respect to
    its own layers' thicknesses and moduli and the ball (a fake solver whose derivative in the k-th parameter
    is k + 1); the row's gradient is the thickness's as it is, the modulus's x E ln 10 for the log10 modulus,
    0 for every flag and for every number of an absent slot."""
    from fixtures.helpers import synthetic_scene_trajectory
    from pcmgn_jax.data.stack import SLOT_NAMES
    from pcmgn_jax.sim import differentiable as dsim
    from pcmgn_jax.sim.parameters import scene_value
    seen = []

    def setup(scenes, preset, *, names, reading):
        layers = [layer.name for layer in scenes[0].layers]
        assert preset == "stack_tiny" and names == [f"{n}.{f}" for n in layers for f in ("thickness", "youngs")] \
            + ["ball.radius", "ball.velocity"]
        seen.append(layers)
        return types.SimpleNamespace(theta=np.array([[scene_value(scenes[0], n) for n in names]]), dt=1e-8, n_sub=3)
    grad = lambda th: np.arange(1.0, th.shape[1] + 1)[None]     # noqa: E731
    monkeypatch.setattr(dsim, "setup", setup)
    monkeypatch.setattr(dsim, "value_fn", lambda gs: lambda th: np.ones(1))
    monkeypatch.setattr(dsim, "value_and_grad_fn", lambda gs: lambda th: (np.ones(1), grad(th)))

    def solve(scene, designs, *, preset):
        return [synthetic_scene_trajectory(scene, {"wall_time_s": 0.1}, n_frames=3)]
    root = ensure_dataset(tmp_path / "s", preset="stack_tiny", n_train=3, n_test=1, seed=0, stack_split="e2",
                          solve_fn=solve, progress=False, batch=1)
    doc = dg.design_gradients(root, "train", n=3, out=tmp_path / "g.json", progress=None)
    assert len(seen) == 3 and {len(s) for s in seen} <= {5, 7}
    for rec, layers in zip(doc["records"], seen):
        solver, g, row = rec["solver_gradient"], rec["gradient"], rec["row"]
        assert list(solver) == [f"{n}.{f}" for n in layers for f in ("thickness", "youngs")] \
            + ["ball.radius", "ball.velocity"]
        assert list(g) == doc["names"] and g["ball.velocity"] == solver["ball.velocity"] == len(solver)
        for slot in SLOT_NAMES:
            assert g[f"{slot}.present"] == 0.0
            if slot not in layers:
                assert g[f"{slot}.thickness"] == g[f"{slot}.log10_youngs"] == 0.0
                continue
            assert g[f"{slot}.thickness"] == solver[f"{slot}.thickness"] > 0
            e = 10.0 ** row[f"{slot}.log10_youngs"]
            assert g[f"{slot}.log10_youngs"] == pytest.approx(solver[f"{slot}.youngs"] * e * np.log(10), rel=1e-12)
        assert {n for n in SLOT_NAMES if n not in layers}        # every e2 training stack lacks a slot


@pytest.mark.slow
def test_the_solver_gradient_at_a_family_design(family_tiny, tmp_path):
    """The real differentiable solver at a family_tiny design (its own mesh pinned): the value agrees with the
    dataset's objective to the step-size difference and the OCA1 derivative with a central difference."""
    from pcmgn_jax.data.splits import load_splits
    from pcmgn_jax.metrics import oled_objective_of
    doc = dg.design_gradients(family_tiny, "train", n=1, out=tmp_path / "g.json", progress=None)
    rec = doc["records"][0]
    truth = float(oled_objective_of(load_splits(family_tiny, n_train=1, n_val=0, n_test=0)[0][0])) * 1e6
    assert rec["objective_pa"] == pytest.approx(truth, rel=0.02)
    assert set(rec["gradient"]) == {"ball.radius", "ball.velocity", "OCA1", "OCA2", "POL"}
    assert all(np.isfinite(list(rec["gradient"].values())))
    assert rec["gradient"]["ball.velocity"] > 0      # a faster ball stresses the OLED more


def _curve_data(tmp_path, *, n_train, n_test, n_grad):
    """A fake-solver tiny dataset of n_train / n_test designs and the gradients of its first n_grad."""
    rng = np.random.default_rng(1)
    root = tmp_path / "d"
    for split, n in (("train", n_train), ("test", n_test)):
        ensure_dataset(root, preset="tiny", designs=rng.uniform(50e-6, 150e-6, (n, 2)), split=split,
                       solve_fn=_fake_solve, progress=False)
    return root, dg.design_gradients(root, "train", n=n_grad, out=tmp_path / "g.json", time_every=1, progress=None)


def test_the_gradient_curve_reads_the_file(fake_solver, tmp_path):
    """The curve (pcmgn_jax.eval.gradient_curve) fits every kind it draws at every size, gek only where the file
    has gradients, charges gek its measured cost in solves, and writes its three files."""
    from pcmgn_jax.eval.gradient_curve import CURVE_KINDS, gradient_curve, write_gradient_curve
    root, doc = _curve_data(tmp_path, n_train=6, n_test=3, n_grad=4)
    for r in doc["records"]:
        r["wall_value_and_grad_s"], r["wall_value_s"] = 5.0, 2.0
    res = gradient_curve(root, doc, sizes=(3, 6), n_test=3, progress=None)
    got = {(p["kind"], p["n"]): p for p in res["points"]}
    assert set(got) == {(k, n) for k in CURVE_KINDS for n in (3, 6)} - {("gek", 6)}
    assert got[("gek", 3)]["solves"] == pytest.approx(7.5) and got[("kriging", 6)]["solves"] == 6
    assert all(np.isfinite(p["error_pct_mean"]) and p["error_pct_max"] >= p["error_pct_mean"] for p in res["points"])
    out = write_gradient_curve(res, tmp_path / "curve", "cmd")
    assert sorted(f.name for f in out.iterdir()) == ["gradient_curve.json", "gradient_curve.md", "gradient_curve.png"]
    assert "2.50 solves" in (out / "gradient_curve.md").read_text()


@pytest.mark.filterwarnings("ignore:Data has no positive values")   # the fake objective: nearest is exact
def test_the_gradient_curve_records_a_refusing_kind(fake_solver, monkeypatch, tmp_path):
    """A kind whose fit or answer refuses a size (ValueError, or SettingError, one of them) is no point: it is
    listed under not_applicable with its reason, its table cell reads n/a, and the other kinds are drawn."""
    from pcmgn_jax.errors import SettingError
    from pcmgn_jax.eval import gradient_curve as gc
    root, doc = _curve_data(tmp_path, n_train=3, n_test=2, n_grad=3)
    fit = gc.fit_objective

    def refusing(kind, train, **options):
        if kind == "gek":
            raise SettingError("gradients", "26 directions are too many here")
        s = fit(kind, train, **options)
        if kind == "kriging":           # refuses at its answer, as the nearest scene does a stack of other layers

            class Refusing:
                fit_seconds = s.fit_seconds

                def predict_objective(self, *a, **k):
                    raise ValueError("kriging of 'area_mean': needs more samples")
            return Refusing()
        return s
    monkeypatch.setattr(gc, "fit_objective", refusing)
    res = gc.gradient_curve(root, doc, sizes=(3,), n_test=2, progress=None)
    assert [(p["kind"], p["n"]) for p in res["points"]] == [("nearest", 3)]
    assert res["not_applicable"] == [
        {"kind": "kriging", "n": 3, "reason": "kriging of 'area_mean': needs more samples"},
        {"kind": "gek", "n": 3, "reason": "gradients: 26 directions are too many here"}]
    text = (gc.write_gradient_curve(res, tmp_path / "curve") / "gradient_curve.md").read_text()
    assert "| n/a | n/a |" in text and "- gek at 3 designs: not applicable: gradients: 26 directions" in text
