"""The suite's pytest fixtures and session set-up; the shared helpers are in ``fixtures/helpers.py``.

The session fixture ``family_tiny`` is the one fixture here that runs the solver (for slow tests).
"""
from __future__ import annotations

import os

import pytest

# the suite never writes the user's persistent compilation cache (pcmgn_jax/compile_cache.py); the
# cache's own tests point it at tmp_path in a subprocess
os.environ["PCMGN_JAX_CACHE"] = "0"

from pcmgn_jax.heap import keep_freed_memory  # noqa: E402

keep_freed_memory()  # before any JAX computation, as the entry points do (pcmgn_jax/heap.py)

from fixtures.helpers import make_synthetic_trajectory, tiny_config  # noqa: E402


@pytest.fixture(scope="session")
def tiny_trajs():
    """Four synthetic trajectories of one topology (designs 0.8..1.2)."""
    return [make_synthetic_trajectory(d) for d in (0.8, 0.93, 1.07, 1.2)]


@pytest.fixture(scope="session")
def tiny_run(tiny_trajs, tmp_path_factory):
    """A short tiny training run: (cfg, workdir, summary). Shared by the training and rollout tests."""
    from pcmgn_jax.train import loop as training
    cfg = tiny_config()
    workdir = tmp_path_factory.mktemp("tiny_run")
    summary = training.train(cfg, workdir, train_trajs=tiny_trajs[:3], val_trajs=tiny_trajs[3:])
    return cfg, workdir, summary


@pytest.fixture(scope="session")
def family_tiny(tmp_path_factory):
    """The family_tiny dataset through the built-in solver (one call per scene; 5 train + 2 test scenes,
    each on its own mesh), made once per session for the slow tests that share it (test_family.py,
    test_imported_dataset.py). Treat it as read-only: its users may only add its ``.cache``."""
    from experiments import generate
    out = tmp_path_factory.mktemp("family_tiny")
    assert generate.main(["--preset", "family_tiny", "--out", str(out), "--no_progress"]) == 0
    return out
