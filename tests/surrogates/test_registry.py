"""pcmgn_jax/surrogates: every registered kind fits and predicts through the one registry; no second list of kinds."""
import ast
import warnings

import numpy as np
import pytest

from fixtures.helpers import ROOT, drop_last_column, make_synthetic_trajectory
from pcmgn_jax.surrogates.kinds import KINDS, Surrogate, choices, kind, names
from pcmgn_jax.surrogates.registry import FITTERS, fit

FITTED = names(baseline=True)   # every kind fitted on trajectories (mgn loads a run: test below)


def _check_fields(us, vms, queries):
    assert len(us) == len(vms) == len(queries)
    for u, vm, q in zip(us, vms, queries):
        assert np.shape(u) == q.displacement.shape and np.shape(vm) == q.von_mises.shape
        assert np.all(np.isfinite(u)) and np.all(np.isfinite(vm))


@pytest.mark.parametrize("name", FITTED)
def test_every_fitted_kind_predicts_finite_fields_of_the_right_shape(name, tiny_trajs):
    """The synthetic set (one mesh, designs 0.8..1.2): each kind's fields on two queries, on their mesh;
    the response surfaces also give the objective readings (part 1 stands in for the OLED), kriging its std."""
    queries = [make_synthetic_trajectory(1.0), make_synthetic_trajectory(1.1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = fit(name, tiny_trajs, queries=queries, readings=("area_mean",), part=1)
        assert isinstance(s, Surrogate) and s.fit_seconds >= 0 and isinstance(s.warnings, list)
        _check_fields(*s.predict_trajectories(queries), queries)
        got = s.predict_objective(queries, reading="area_mean", part=1, return_std=KINDS[name].std)
        for values in (got if KINDS[name].std else (got,)):
            assert values.shape == (2,) and np.all(np.isfinite(values))


@pytest.mark.parametrize("name", [n for n in FITTED if KINDS[n].fields == "shared"])
def test_a_shared_mesh_kind_predicts_designs_and_refuses_other_meshes(name, tiny_trajs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        u, vm = fit(name, tiny_trajs).predict(np.array([[100e-6], [110e-6]]))
    ref = tiny_trajs[0]
    assert u.shape == (2,) + ref.displacement.shape and vm.shape == (2,) + ref.von_mises.shape
    other = drop_last_column(make_synthetic_trajectory(1.0))   # another mesh: not the training topology
    with pytest.raises(ValueError), warnings.catch_warnings():   # poly2/rbf: no fit; a surface: no field surface
        warnings.simplefilter("ignore")
        fit(name, tiny_trajs, queries=[other], readings=("area_mean",), part=1).predict_trajectories([other])


def test_a_kind_not_in_the_registry_is_an_error_naming_it(tiny_trajs):
    with pytest.raises(ValueError, match=r"no predictor kind 'krigging'.*registered kinds"):
        fit("krigging", tiny_trajs)
    with pytest.raises(ValueError, match="'poly3'"):
        kind("poly3")
    with pytest.raises(ValueError, match="no field 'colour'"):
        names(colour=True)


def test_every_list_of_predictors_is_the_registrys():
    """The families are the registry's; the config's residual bases, evaluate's baselines, the explorer's
    predictors and the optimiser's and active loop's choices are subsets of KINDS chosen by a field."""
    from pcmgn_jax.config import RESIDUAL_BASES
    from pcmgn_jax.eval.baselines import BASELINES
    from pcmgn_jax.explore.types import LABELS, PREDICTORS
    from pcmgn_jax.opt.active import ACTIVE_SURROGATES as ACTIVE
    from pcmgn_jax.opt.pipeline import SURROGATES as OPTIMISE

    assert {k.family for k in KINDS.values()} == set(FITTERS)
    assert RESIDUAL_BASES == ("",) + names(residual_base=True) and "rom" in RESIDUAL_BASES
    trained = ("mgn", "time_fields")   # the families of trained runs (a workdir): never a baseline
    graded = names(gradients=True)   # fitted with the solver's gradients, which a dataset does not hold: no baseline
    assert BASELINES == tuple(n for n, k in KINDS.items() if k.family not in trained and n not in graded)
    assert PREDICTORS[0] == "mgn"
    assert set(LABELS) == set(PREDICTORS) == set(names(explore=True))
    assert OPTIMISE == choices("optimise") and ACTIVE == choices("active") and OPTIMISE[-1] == ACTIVE[-1] == "auto"


def test_no_second_list_of_kinds_in_the_code():
    """No literal in the library, the entry points or the benchmarks names three or more registered kinds
    (a list of predictors written out again, instead of derived from pcmgn_jax/surrogates/kinds.py)."""
    found = []
    for folder in ("pcmgn_jax", "experiments", "benchmarks"):
        for f in sorted((ROOT / folder).rglob("*.py")):
            if f.name == "kinds.py":
                continue
            for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
                elts = node.keys if isinstance(node, ast.Dict) else \
                    node.elts if isinstance(node, (ast.Tuple, ast.List, ast.Set)) else []
                hits = [e.value for e in elts if isinstance(e, ast.Constant) and e.value in KINDS]
                if len(hits) >= 3:
                    found.append(f"{f.relative_to(ROOT)}:{node.lineno} {hits}")
    assert not found, f"lists of predictor kinds outside the registry: {found}"


@pytest.mark.slow  # trains the tiny run (shared with the rollout tests)
def test_the_mgn_kind_loads_a_run_and_predicts_fields(tiny_run, tiny_trajs):
    _, workdir, _ = tiny_run
    s = fit("mgn", tiny_trajs[:3], workdir=workdir)
    assert isinstance(s, Surrogate)
    _check_fields(*s.predict_trajectories(tiny_trajs[3:]), tiny_trajs[3:])
    with pytest.raises(TypeError):
        fit("mgn", tiny_trajs, workdir=workdir, readings=("area_mean",))   # a surface's option: refused
