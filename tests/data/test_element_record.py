"""Datasets cannot mix solver elements: the manifest and every solver trajectory record the element, and a
dataset made with another element (the old full-integration ``q4``) is refused by name, before anything is
written."""
from __future__ import annotations

import json
import sys

import pytest

from fixtures.synthetic import FakeSolver, synthetic_trajectory
from pcmgn_jax.data import dataset as ds, layout
from pcmgn_jax.data.splits import prepare_dataset
from pcmgn_jax.sim import fem


@pytest.fixture
def fake(monkeypatch):
    mod = FakeSolver()
    monkeypatch.setitem(sys.modules, "pcmgn_jax.sim.solver", mod)
    return mod


def test_the_manifest_records_the_element_and_an_old_dataset_is_refused(tmp_path, fake):
    out = tmp_path / "data"
    ds.ensure_dataset(out, preset="tiny", n_train=2, n_test=1, seed=0, batch=2, progress=False)
    man = json.loads((out / "manifest.json").read_text())
    assert man["element"] == fem.DEFAULT_ELEMENT == "q4i"
    # a manifest from before the record: the old element, refused by every way in, nothing rewritten
    del man["element"]
    (out / "manifest.json").write_text(json.dumps(man))
    before = (out / "manifest.json").read_bytes()
    fake.calls.clear()
    with pytest.raises(ds.DatasetError, match=r"manifest.json: generated with the 'q4' element, the solver now "
                                              r"makes 'q4i'"):
        ds.ensure_dataset(out, preset="tiny", n_train=2, n_test=1, seed=0, batch=2, progress=False)
    with pytest.raises(ds.DatasetError, match="'q4' element"):
        prepare_dataset(out, preset="tiny", n_train=2, n_test=1, seed=0)
    assert (out / "manifest.json").read_bytes() == before and fake.calls == []


def test_a_trajectory_of_another_element_disagrees_with_its_manifest():
    made = {"solver": {"settings": {"element": "q4"}}}
    assert layout.trajectory_element(made) == "q4"
    assert layout.trajectory_element({"solver": {"settings": {}}}) == layout.LEGACY_ELEMENT   # predates the record
    assert layout.trajectory_element(synthetic_trajectory().meta) is None                  # not the solver's
    entry = {"design_m": [1e-4, 1e-4]}
    why = layout.entry_mismatch(entry, made, ("OCA1", "OCA2"), "q4i")
    assert why == "element 'q4i' in the manifest, 'q4' in the trajectory"
    assert layout.entry_mismatch(entry, made, ("OCA1", "OCA2"), "q4") is None


@pytest.mark.slow  # ~12 s: a tiny generation
def test_the_solver_records_its_element_in_every_trajectory():
    from pcmgn_jax.scene import default_scene
    from pcmgn_jax.sim import solver

    scene = default_scene()
    for element in fem.Q4_ELEMENTS:
        settings = solver.SolverSettings(element=element)
        result = solver.simulate([scene], "tiny", n_frames=2, settings=settings)
        (traj,) = solver.to_trajectories(result, [scene], "tiny", settings=settings)
        assert layout.trajectory_element(traj.meta) == element


def test_a_run_trained_on_the_old_element_is_refused(tmp_path):
    """RUN/data.json without an element record, of generated data: trained before the record, i.e. on q4."""
    from pcmgn_jax.data.layout import DatasetError, check_run_element

    with pytest.raises(DatasetError, match=r"trained on 'q4'-element trajectories, the solver now makes 'q4i'"):
        check_run_element(tmp_path, {"source": "generate", "train": []})
    check_run_element(tmp_path, {"source": "imported"})                 # imported data: no element to know
    check_run_element(tmp_path, {"source": "generate", "element": "q4i"})
    check_run_element(tmp_path, {"source": "generate", "element": None})   # synthetic trajectories
    old = synthetic_trajectory(meta={"name": "test_0003", "solver": {"settings": {"element": "q4"}}})
    with pytest.raises(DatasetError, match="test_0003: made with the 'q4' element"):
        check_run_element(tmp_path, None, [old])
