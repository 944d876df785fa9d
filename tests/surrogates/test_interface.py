"""The one surrogate interface: every kind answers the objective (and fields where it has them) through the same
calls, or refuses with kinds.CannotAnswer naming itself; a new kind is one Kind row and one fit function."""
import types
import warnings

import numpy as np
import pytest

from fixtures.helpers import make_synthetic_trajectory
from pcmgn_jax.data.family import Design
from pcmgn_jax.metrics import oled_objective_of
from pcmgn_jax.surrogates import registry
from pcmgn_jax.surrogates.inputs import TrainingScenes, design_of
from pcmgn_jax.surrogates.kinds import KINDS, CannotAnswer, Kind, Surrogate
from pcmgn_jax.surrogates.objective import FromFields

PART = 1   # the synthetic set's part that stands in for the OLED


@pytest.fixture(scope="module")
def queries():
    return [make_synthetic_trajectory(1.0), make_synthetic_trajectory(1.1)]


def _truth(queries, reading="area_mean"):
    return np.array([float(oled_objective_of(q, part=PART, reading=reading)) for q in queries])


class _Echo(FromFields):
    """A toy fields kind: each query's own fields (a perfect predictor), refusing designs alone."""

    def __init__(self, name):
        self.name, self.fit_seconds, self.warnings = name, 0.0, []

    def predict_trajectories(self, trajs):
        return [t.displacement for t in trajs], [t.von_mises for t in trajs]

    def predict(self, designs_m):
        raise CannotAnswer(self.name, "fields at designs alone", "a toy")


def test_a_new_kind_is_one_row_and_one_fit(monkeypatch, tiny_trajs, queries):
    """A newcomer's kind: a Kind row and a fit function (a family of FITTERS); fields and objective come through
    the protocol (the objective by the shared metric of its fields), what it lacks is refused by name."""
    monkeypatch.setitem(KINDS, "echo", Kind("echo", "toy echo", "toy", baseline=False, explore=False))
    monkeypatch.setitem(registry.FITTERS, "toy", lambda name, train, **_: _Echo(name))
    s = registry.fit("echo", tiny_trajs)
    assert isinstance(s, Surrogate)
    us, vms = s.predict_trajectories(queries)
    assert np.array_equal(vms[1], queries[1].von_mises)
    np.testing.assert_allclose(s.predict_objective(queries, reading="area_mean", part=PART), _truth(queries))
    with pytest.raises(CannotAnswer, match=r"echo: cannot answer a posterior std"):
        s.predict_objective(queries, reading="area_mean", part=PART, return_std=True)
    with pytest.raises(CannotAnswer, match=r"echo: cannot answer the objective reading 'median'"):
        s.predict_objective(queries, reading="median", part=PART)


def _mgn(queries):
    """The mgn kind without a run: its class, its rollout replaced by the queries' own fields."""
    from pcmgn_jax.surrogates.mgn import MGNSurrogate
    s = object.__new__(MGNSurrogate)
    s.fit_seconds, s.warnings, s.residual_of = 0.0, [], ""
    s.rollout_trajectories = lambda trajs: _Echo("mgn").predict_trajectories(trajs)
    return s


def _onepass(queries):
    """The onepass kind without a run: its class, its run's prediction the queries' own time fields."""
    from pcmgn_jax.surrogates.onepass import OnePassSurrogate
    s = object.__new__(OnePassSurrogate)
    s.readings, s.part, s.fit_seconds, s.warnings = ("area_mean", "peak"), PART, 0.0, []

    def predict(designs):
        return [np.stack([d["von_mises"].mean(0), d["von_mises"].max(0),
                          np.linalg.norm(d["displacement"], axis=-1).max(0)], axis=-1) for d in designs]
    s.run = types.SimpleNamespace(inputs=lambda t: {"von_mises": t.von_mises, "displacement": t.displacement},
                                  predict=predict, cfg=types.SimpleNamespace(objective_part="OLED"))
    return s


RUNS = {"mgn": _mgn, "time_fields": _onepass}   # the families of trained runs, built here without one


def _two_parameters(trajs):
    """Copies of ``trajs`` as scenes of two parameters (SMT's GEKPLS needs >= 2): radius and speed per design."""
    import dataclasses
    out = []
    for i, t in enumerate(trajs):
        d = float(np.asarray(t.meta["design"] if not isinstance(t.meta["design"], dict)
                             else list(t.meta["design"].values()))[0])
        params = {"ball.radius": 5e-3 * d, "ball.velocity": 0.5 + 0.05 * ((3 * i) % 5)}
        out.append(dataclasses.replace(t, meta={**t.meta, "scene_params": params}))
    return out


def _extra(name, train, queries):
    """(train, queries, options) of a kind: gek on two scene parameters with the objective's gradients at the
    training designs (zeros); the others as they are."""
    if name != "gek":
        return train, queries, {}
    train, queries = _two_parameters(train), _two_parameters(queries)
    zeros = {n: np.zeros(len(train)) for n in ("ball.radius", "ball.velocity")}
    return train, queries, {"gradients": {"area_mean": zeros}}


@pytest.mark.parametrize("name", list(KINDS))
def test_every_kind_answers_the_objective_or_refuses_by_name(name, tiny_trajs, queries):
    """Every registered kind, fitted on the tiny set (a trained run's kind: its class without the run), answers
    predict_objective (B,) [MPa] finite, its std only where the Kind says so, and fields or CannotAnswer."""
    spec = KINDS[name]
    train, queries, options = _extra(name, tiny_trajs, queries)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = RUNS[spec.family](queries) if spec.family in RUNS else \
            registry.fit(name, train, queries=queries, readings=("area_mean",), part=PART, **options)
        assert isinstance(s, Surrogate)
        f = s.predict_objective(queries, reading="area_mean", part=PART)
        assert f.shape == (2,) and np.all(np.isfinite(f))
        if spec.std:
            mean, std = s.predict_objective(queries, reading="area_mean", part=PART, return_std=True)
            np.testing.assert_allclose(mean, f)
            assert np.all(std >= 0)
        else:
            with pytest.raises(CannotAnswer, match=rf"^{name}: cannot answer a posterior std"):
                s.predict_objective(queries, reading="area_mean", part=PART, return_std=True)
        designs = [Design.of(None, list(q.meta["scene_params"].values()), list(q.meta["scene_params"]))
                   if "scene_params" in q.meta else Design.of(None, design_of(q), ("CG",))   # the synthetic layer
                   for q in queries]
        if s.objective_surface:   # read at designs alone: its value at the queries' own parameters
            assert s.predict_objective_at(designs, reading="area_mean", part=PART).tolist() == f.tolist()
        else:
            with pytest.raises(CannotAnswer, match=rf"^{name}: cannot answer the objective at designs alone"):
                s.predict_objective_at(designs, reading="area_mean", part=PART)
        assert s.objective_surface == (spec.family == "surface")
        if spec.fields:
            us, vms = s.predict_trajectories(queries)
            assert [np.shape(v) for v in vms] == [q.von_mises.shape for q in queries]
        else:
            with pytest.raises(CannotAnswer, match=rf"^{name}: cannot answer"):
                s.predict_trajectories(queries)
    if name == "mgn":   # its (echoed) fields scored by the shared metric: the queries' own objective
        np.testing.assert_allclose(f, _truth(queries), rtol=1e-6)


def test_an_objective_surface_asked_for_fields_refuses_by_name(tiny_trajs, queries):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = registry.fit("mop", tiny_trajs, readings=("area_mean",), part=PART, fields=False)
    assert s.predict_objective(queries, reading="area_mean", part=PART).shape == (2,)
    with pytest.raises(CannotAnswer, match="mop: cannot answer fields: it is an objective surface"):
        s.predict_trajectories(queries)
    with pytest.raises(CannotAnswer, match="mop: cannot answer the objective reading 'peak'"):
        s.predict_objective(queries, reading="peak", part=PART)
    with pytest.raises(CannotAnswer, match="mop: cannot answer the objective of part 0"):
        s.predict_objective(queries, reading="area_mean", part=0)


def test_a_design_is_asked_by_its_canonical_row_in_the_training_order(tiny_trajs):
    """TrainingScenes.rows: Designs in any order of names give the training parameters' order; a stack's absent
    layer is zeroed (its canonical row); a missing parameter is refused by name, an unknown one noted."""
    from pcmgn_jax.data.stack import STACK_FAMILIES
    ts = TrainingScenes(tiny_trajs)
    notes = []
    assert ts.rows([Design.of(None, [90e-6], ("CG",))], notes.append).tolist() == [[90e-6]] and not notes
    assert ts.rows([Design(None, (("x", 1.0), ("CG", 90e-6)))], notes.append).tolist() == [[90e-6]]
    assert notes == ["design 0: scene parameter x = 1 unknown to the model (not a training parameter): answered "
                     "as if it were unchanged"]
    with pytest.raises(ValueError, match=r"design 0: scene parameter 'CG' missing from the design"):
        ts.rows([Design(None, (("x", 1.0),))], notes.append)
    fam = STACK_FAMILIES["stack_tiny"]
    row = dict(zip(fam.names, fam.sample(1, seed=0, layer_counts=(5,))[0]))
    absent = next(n for n in fam.names if n.endswith(".present") and row[n] == 0).replace("present", "thickness")
    stacks = object.__new__(TrainingScenes)
    stacks.names = tuple(reversed(fam.names))
    got = stacks.rows([Design(fam, tuple({**row, absent: 7e-6}.items()))], notes.append)[0]
    assert got[stacks.names.index(absent)] == 0.0 and got.tolist() == [row[n] for n in stacks.names]


def test_no_response_surface_is_built_outside_the_surrogates():
    """Kriging / MOP / PodGP are constructed in pcmgn_jax/surrogates only; elsewhere a GP of other data is
    surface_fit.fit_gp (or fit_surface), a kind's surface registry.fit."""
    import ast

    from fixtures.helpers import ROOT
    found = []
    for folder in ("pcmgn_jax", "experiments", "benchmarks"):
        for f in sorted((ROOT / folder).rglob("*.py")):
            if f.parent == ROOT / "pcmgn_jax" / "surrogates":
                continue
            for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ImportFrom) and (node.module or "").endswith("surface_fit"):
                    found += [f"{f.relative_to(ROOT)}:{node.lineno} {a.name}" for a in node.names
                              if a.name in ("Kriging", "MOP", "PodGP", "SURFACES")]
    assert not found, f"response surfaces built outside pcmgn_jax/surrogates (use surface_fit.fit_gp): {found}"
