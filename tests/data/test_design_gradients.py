"""Gradients at a dataset's designs (pcmgn_jax.data.gradients): one record per design, written as it goes and
resumed after a kill, refused for another dataset's file, matched to designs by their rows, its cost in solves.
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
    assert dg.solver_parameter("OCA1", ["CG", "OCA1"]) == "OCA1.thickness"
    assert dg.solver_parameter("ball.velocity", ["CG"]) == "ball.velocity"
    with pytest.raises(ValueError, match="'OCA1.log10_youngs' has no solver parameter"):
        dg.solver_parameter("OCA1.log10_youngs", ["OCA1"])


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


def test_the_gradient_curve_reads_the_file(fake_solver, tmp_path):
    """The curve (pcmgn_jax.eval.gradient_curve) fits every kind it draws at every size, gek only where the file
    has gradients, charges gek its measured cost in solves, and writes its three files."""
    from pcmgn_jax.eval.gradient_curve import CURVE_KINDS, gradient_curve, write_gradient_curve
    rng = np.random.default_rng(1)
    root = tmp_path / "d"
    for split, n in (("train", 6), ("test", 3)):
        ensure_dataset(root, preset="tiny", designs=rng.uniform(50e-6, 150e-6, (n, 2)), split=split,
                       solve_fn=_fake_solve, progress=False)
    doc = dg.design_gradients(root, "train", n=4, out=tmp_path / "g.json", time_every=1, progress=None)
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
