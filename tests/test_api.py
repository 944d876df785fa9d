"""The script API (pcmgn_jax/api.py) and its page (docs/api.md): the page's code blocks run, in order, on a
tiny run (three tiny-preset solver trajectories of an 8-frame window, a small model trained for a few
steps); the rollout of a second design reuses the first one's compilation; the gradient through the rollout
matches a central difference of the same function.
"""
from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from fixtures.helpers import ROOT, CompileCounter, tiny_solver_dataset

PAGE = ROOT / "docs" / "api.md"


@pytest.fixture(scope="module")
def solver_run(tmp_path_factory):
    """A run folder trained on solver data: config.json over a tiny-preset dataset, a best checkpoint."""
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.data.splits import load_splits
    from pcmgn_jax.train import loop as training

    root = tmp_path_factory.mktemp("api")
    data, run = tiny_solver_dataset(root, n_train=3, n_frames=8), root / "run"
    cfg = TrainConfig.from_preset("tiny", dataset_dir=str(data), n_train=2, n_val=1, n_test=0, num_steps=20,
                                  steps_per_dispatch=10, log_every=10, ckpt_every=20, val_every=20,
                                  latent_size=16, message_passing_steps=2, progress=False)
    train, val, _ = load_splits(data, n_train=2, n_val=1, n_test=0)
    training.train(cfg, run, train_trajs=train, val_trajs=val)
    return run


def page_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", PAGE.read_text(encoding="utf-8"), flags=re.S)


@pytest.mark.slow   # makes a solver dataset and trains (~1 min on 2 cores)
def test_the_pages_code_runs_on_a_tiny_run(solver_run):
    blocks = page_blocks()
    assert len(blocks) >= 3
    scope: dict = {}
    for code in blocks:
        exec(compile(code.replace('"runs/cpu"', repr(str(solver_run))), str(PAGE), "exec"), scope)
    model, pred, truth = scope["model"], scope["pred"], scope["truth"]
    assert pred.displacement.shape == truth.displacement.shape == (9, pred.n_nodes, 2)
    assert np.array_equal(pred.cells, truth.cells) and np.allclose(pred.points, truth.points)
    assert np.isfinite(model.objective(pred)) and model.objective(truth) > 0
    assert np.isfinite(float(scope["value"])) and np.all(np.isfinite(np.asarray(scope["grad"])))


@pytest.mark.slow
def test_rollouts_reuse_one_compilation_and_the_gradient_is_the_difference_quotient(solver_run):
    import jax
    import jax.numpy as jnp

    from pcmgn_jax.api import load_run

    model = load_run(solver_run)
    model.rollout(model.scene.with_design(90e-6, 110e-6))
    with CompileCounter("_rollout") as counter:
        again = model.rollout(model.scene.with_design(120e-6, 70e-6))
    assert counter.count == 0 and np.isfinite(again.von_mises).all()
    f = jax.jit(model.design_objective())
    d = jnp.asarray(model.scene.design, jnp.float32)
    g = np.asarray(jax.grad(f)(d))
    h = 2e-6
    for k in range(len(d)):
        e = jnp.zeros_like(d).at[k].set(h)
        fd = (float(f(d + e)) - float(f(d - e))) / (2 * h)
        assert g[k] == pytest.approx(fd, rel=0.1, abs=1e-3 * np.abs(g).max())
    # the function's value is the rollout's objective at the same design (to float32 round-off)
    assert float(f(d)) == pytest.approx(model.objective(model.rollout(model.scene)), rel=1e-3)


def test_load_run_refuses_a_folder_without_a_run(tmp_path):
    from pcmgn_jax.api import load_run
    from pcmgn_jax.mgn.checkpoint import MissingRun

    with pytest.raises(MissingRun, match="no config.json"):
        load_run(tmp_path)
    with pytest.raises(MissingRun, match="no such run folder"):
        load_run(tmp_path / "nowhere")


def test_a_synthetic_run_rolls_out_a_trajectory_and_refuses_scenes(tiny_run, tiny_trajs):
    """On a run of imported-like data (no mesh preset): a trajectory rolls out on its own mesh, equal to the
    surrogate's rollout of it; a Scene is refused by name."""
    from pcmgn_jax.api import load_run
    from pcmgn_jax.surrogates.mgn import MGNSurrogate

    _, workdir, _ = tiny_run
    model = load_run(workdir, reference=tiny_trajs[0])
    assert model.preset is None
    pred = model.rollout(tiny_trajs[3])
    u, vm = MGNSurrogate(workdir, tiny_trajs[0]).rollout_trajectories([tiny_trajs[3]])
    np.testing.assert_allclose(pred.displacement, u[0], atol=1e-9)
    np.testing.assert_allclose(pred.von_mises, vm[0], rtol=1e-5, atol=1.0)
    assert pred.meta["source"] == "mgn" and pred.n_frames == tiny_trajs[3].n_frames
    with pytest.raises(ValueError, match="names no mesh preset"):
        model.rollout(model.scene)
    with pytest.raises(ValueError, match="steps by"):
        model.design_objective(dataclasses.replace(model.scene, output_dt=1e-6))
