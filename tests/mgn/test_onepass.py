"""The one-pass model (pcmgn_jax/mgn/onepass.py, pcmgn_jax/train/onepass.py, the ``onepass`` kind): shapes, the
objective identity, training, resume, refusals, no recompilation. Synthetic tiny trajectories (one topology);
their objective part is the cover glass (they have no OLED)."""
from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from fixtures.helpers import CompileCounter
from pcmgn_jax import metrics
from pcmgn_jax.mgn import onepass as op
from pcmgn_jax.surrogates.kinds import kind
from pcmgn_jax.surrogates.registry import fit
from pcmgn_jax.train import onepass as training

CG = 1   # the synthetic trajectories' cover glass: the objective's part here


def _cfg(**kw):
    base = dict(latent_size=16, message_passing_steps=2, num_steps=40, batch_graphs=2, log_every=5, val_every=10,
                ckpt_every=10, objective_part="CG", n_train=3, n_val=1, n_test=0, ema_decay=0.9)
    return op.OnePassConfig(**{**base, **kw})


@pytest.fixture(scope="module")
def run40(tiny_trajs, tmp_path_factory):
    workdir = tmp_path_factory.mktemp("onepass")
    with CompileCounter("onepass_step") as steps:
        summary = training.train(_cfg(), workdir, train_trajs=tiny_trajs[:3], val_trajs=tiny_trajs[3:], progress=None)
    return workdir, summary, steps.count


@pytest.mark.slow  # trains the tiny one-pass run (~50 s on the loaded 2-core machine)
def test_time_targets_and_shapes(tiny_trajs, run40):
    t = tiny_trajs[0]
    y = op.time_targets(t)
    assert y.shape == (t.n_nodes, 3)
    np.testing.assert_allclose(y[:, 0], t.von_mises.mean(0))
    np.testing.assert_allclose(y[:, 1], t.von_mises.max(0))
    np.testing.assert_allclose(y[:, 2], np.linalg.norm(t.displacement, axis=-1).max(0))
    run = op.load(run40[0])
    out = run.predict([run.inputs(x) for x in tiny_trajs[:2]])
    assert len(out) == 2 and all(f.shape == (t.n_nodes, 3) and np.isfinite(f).all() for f in out)


@pytest.mark.parametrize("reading", metrics.OBJECTIVES)
def test_objective_of_the_time_fields_is_the_objective(tiny_trajs, reading):
    """The time mean of the section mean = the section mean of the time-mean field (linear readings); the peak
    over frames and nodes = the peak field's max over the section."""
    t = tiny_trajs[1]
    w = metrics.objective_weights(t.points, t.cells, t.cell_part, t.node_part, part=CG, reading=reading)
    truth = metrics.oled_objective(t.von_mises, w, reading=reading)
    y = op.time_targets(t)
    field = y[:, 1] if reading == "peak" else y[:, 0]
    assert truth > 0
    np.testing.assert_allclose(metrics.oled_objective(field[None], w, reading=reading), truth, rtol=1e-12)
    if reading != "peak":   # and not the peak field's (the identity is not vacuous)
        assert abs(metrics.oled_objective(y[:, 1][None], w, reading=reading) - truth) > 1e-3 * truth


@pytest.mark.slow  # trains the tiny one-pass run (~50 s on the loaded 2-core machine)
def test_loss_decreases_and_compiles_once(run40):
    workdir, summary, compiles = run40
    lines = [json.loads(x) for x in (workdir / "metrics.jsonl").read_text().splitlines()]
    losses = [r["loss"] for r in lines if "loss" in r]
    assert summary["step"] == 40 and len(losses) == 8
    assert losses[-1] < 0.5 * losses[0], losses
    assert compiles == 1
    assert np.isfinite(summary["best_val_objective_error_pct"])


@pytest.mark.slow  # trains the tiny one-pass run (~50 s on the loaded 2-core machine)
def test_resume_after_a_kill_equals_an_uninterrupted_run(tiny_trajs, run40, tmp_path):
    kw = dict(train_trajs=tiny_trajs[:3], val_trajs=tiny_trajs[3:], progress=None)
    stopped = training.train(_cfg(), tmp_path, stop_after=25, **kw)
    assert stopped == {"step": 25, "stopped": True}
    with pytest.raises(ValueError, match="workdir: .* holds a run already: resume it"):
        training.train(_cfg(), tmp_path, **kw)
    with pytest.raises(ValueError, match="other settings"):
        training.train(_cfg(lambda_obj=1.0), tmp_path, resume=True, **kw)
    summary = training.train(_cfg(), tmp_path, resume=True, **kw)
    assert summary["step"] == 40 and summary["steps_this_call"] == 20   # from the step-20 checkpoint
    a, b = op.load(run40[0], "periodic").params, op.load(tmp_path, "periodic").params
    jax.tree.map(lambda x, y: np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-7), a, b)
    logged = [json.loads(x)["step"] for x in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert logged == sorted(set(logged))   # no step logged twice


@pytest.mark.slow  # trains the tiny one-pass run (~50 s on the loaded 2-core machine)
def test_the_kind_answers_the_objective_and_refuses_per_frame_fields(tiny_trajs, run40):
    assert kind("onepass").fields == "" and not kind("onepass").baseline
    s = fit("onepass", workdir=run40[0])
    got = s.objectives(tiny_trajs)
    assert set(got) == set(metrics.OBJECTIVES) and all(np.isfinite(v).all() and v.shape == (4,) for v in got.values())
    run = op.load(run40[0])
    t = tiny_trajs[0]
    w = metrics.objective_weights(t.points, t.cells, t.cell_part, t.node_part, part=CG)
    mean = run.predict([run.inputs(t)])[0][:, 0]
    np.testing.assert_allclose(got["area_mean"][0], mean @ w * 1e-6, rtol=1e-6)
    for method, arg in (("predict_trajectories", tiny_trajs), ("predict", np.zeros((1, 1)))):
        with pytest.raises(ValueError, match="von_mises"):
            getattr(s, method)(arg)
    with CompileCounter("onepass_predict") as c:
        s.objectives(tiny_trajs)
        s.objectives(tiny_trajs)
    assert c.count == 0   # compiled by the first call above: no recompilation after warm-up


def test_bad_config_and_missing_run_are_named(tmp_path):
    with pytest.raises(ValueError, match="num_steps"):
        op.OnePassConfig(num_steps=0)
    with pytest.raises(ValueError, match="onepass.json"):
        fit("onepass", workdir=tmp_path)
