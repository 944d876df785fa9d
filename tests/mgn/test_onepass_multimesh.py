"""The one-pass model on multi-mesh datasets (issue 49 item 4): a stack family's designs of 5, 6 and 7 layers (each on
its own ``stack_tiny`` mesh, synthetic fields: no solver) train together as padded unions of one size, without a
recompilation after warm-up; the graph settings come from the dataset's manifest; the union's loss is the mean of
each design's own; (slow) ``experiments.onepass`` end to end on a tiny scene-family and a tiny e2 stack
dataset (fake solver)."""
from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from fixtures.helpers import CompileCounter, fake_scene_solve, synthetic_stack
from pcmgn_jax import metrics
from pcmgn_jax.mgn import onepass as op, onepass_union as union
from pcmgn_jax.presets import STACK_FEATURES
from pcmgn_jax.surrogates.registry import fit
from pcmgn_jax.train import onepass as training


def _cfg(preset="stack_tiny", **kw):
    base = dict(latent_size=16, message_passing_steps=2, num_steps=6, batch_graphs=2, log_every=3, val_every=3,
                ckpt_every=3, n_train=4, n_val=1, n_test=0, ema_decay=0.9)
    return training.for_dataset(op.OnePassConfig(**{**base, **kw}), {"preset": preset})


@pytest.fixture(scope="module")
def stacks():
    """Training stacks of 5 and 7 layers, a validation stack of 6: five meshes of different node counts."""
    train = [synthetic_stack(c, s, n_frames=4) for c, s in ((5, 1), (7, 2), (5, 3), (7, 4))]
    return train, [synthetic_stack(6, 5, n_frames=4)]


def test_the_manifest_decides_the_graph_settings():
    cfg = _cfg()
    assert (cfg.preset, cfg.part_identity, cfg.origin, cfg.scene_features) == \
        ("stack_tiny", "role", "contact_top", STACK_FEATURES)
    fam = _cfg("family_tiny")
    assert (fam.part_identity, fam.origin, fam.scene_features) == ("type", "support_top",
                                                                  ("ball_radius", "layer_thickness"))
    box = _cfg("cpu")
    assert (box.part_identity, box.origin, box.scene_features) == ("type", "mesh", ("layer_thickness",))
    given = training.for_dataset(op.OnePassConfig(scene_features=("ball_radius", "layer_thickness")),
                                 {"preset": "family_tiny"}, given={"scene_features"})
    assert given.scene_features == ("ball_radius", "layer_thickness") and given.origin == "support_top"
    assert training.for_dataset(op.OnePassConfig(), None) == op.OnePassConfig()   # imported: as given
    with pytest.raises(ValueError, match="preset 'nope'"):
        training.for_dataset(op.OnePassConfig(), {"preset": "nope"})


def test_a_union_of_designs_is_each_design_on_its_own(stacks):
    """The union's loss = the mean of each design's loss alone (padding and the other designs never leak in); its
    prediction gives every design its own node count."""
    cfg = _cfg()
    radius = float(op.design_inputs(cfg, stacks[0][0])["index"].radius)
    designs = [op.design_inputs(cfg, t, radius=radius, capacity=64) for t in stacks[0][:2]]
    targets = [op.time_targets(t) for t in stacks[0][:2]]
    stats = op.compute_stats(cfg, designs, targets, scene=stacks[0][0].meta["scene"])
    data = training.Data(cfg, designs, targets, [training._section(cfg, t) for t in stacks[0][:2]], 2)
    model, form = cfg.model(), cfg.formulation
    u2 = data.take([0, 1])
    params = union.init_params(form, model, stats, u2[0], 0)
    loss = jax.jit(lambda p, *a: union.loss_fn(p, form, model, stats, *a, 10.0))
    both = loss(params, *u2)
    alone = []
    for i in (0, 1):
        one = training.Data(cfg, [designs[i]], [targets[i]], [data.obj_w[i]], 1)
        alone.append(loss(params, *one.take([0])))
    np.testing.assert_allclose(float(both[0]), np.mean([float(a[0]) for a in alone]), rtol=1e-4)
    np.testing.assert_allclose(float(both[1][1]), np.mean([float(a[1][1]) for a in alone]), rtol=1e-4)
    together = op.predict_fields(cfg, params, stats, designs, slots=2)
    assert [f.shape for f in together] == [(d["topology"].n_node, 3) for d in designs]
    assert all(np.isfinite(f).all() for f in together)


@pytest.mark.slow  # 25 s here; the union test stays in the default suite
def test_training_on_stacks_of_several_meshes_compiles_once(stacks, tmp_path):
    train, val = stacks
    assert len({t.n_nodes for t in train + val}) == 5
    cfg = _cfg()
    with CompileCounter("onepass_step") as steps:
        summary = training.train(cfg, tmp_path, train_trajs=train, val_trajs=val, progress=None)
    assert summary["step"] == 6 and steps.count == 1   # six draws of different mesh pairs, one compilation
    print(f"one-pass step on stack_tiny (batch 2): {summary['step_seconds'] * 1e3:.1f} ms, first (compiling) "
          f"{summary['first_step_seconds']:.1f} s")
    assert np.isfinite(summary["best_val_objective_error_pct"]) and np.isfinite(summary["step_seconds"])
    losses = [json.loads(x)["loss"] for x in (tmp_path / "metrics.jsonl").read_text().splitlines()
              if "loss" in json.loads(x)]
    assert losses and np.isfinite(losses).all()
    s = fit("onepass", workdir=tmp_path)
    assert s.run.cfg.part_identity == "role" and s.run.stats.target_mean.shape == (6, 3)   # the six roles
    queries = val + train[:1]   # a 6-layer and a 5-layer stack in one union
    fields = s.time_fields(queries)
    assert [f.shape for f in fields["mean_von_mises"]] == [(t.n_nodes,) for t in queries]
    assert all(np.isfinite(f).all() for v in fields.values() for f in v)
    got = s.objectives(queries)
    assert all(v.shape == (2,) and np.isfinite(v).all() for v in got.values())
    t = val[0]   # the objective by the metric code, on the design's own mesh
    w = metrics.objective_weights(t.points, t.cells, t.cell_part, t.node_part, part=op.part_id(t, "OLED"))
    np.testing.assert_allclose(got["area_mean"][0], metrics.oled_objective(fields["mean_von_mises"][0][None], w),
                               rtol=1e-6)
    with CompileCounter("onepass_predict") as c:
        s.objectives(queries)
    assert c.count == 0


@pytest.mark.slow  # a fake-solver dataset, a few steps, kriging and the scoring (~20 s each, loaded)
@pytest.mark.parametrize("preset, origin, split", [("family_tiny", "support_top", {}),
                                                   ("stack_tiny", "contact_top", {"stack_split": "e2"})])
def test_experiment_end_to_end_on_a_multi_mesh_dataset(tmp_path, preset, origin, split):
    from experiments import onepass as exp
    from pcmgn_jax.data.dataset import ensure_dataset
    data = ensure_dataset(tmp_path / "data", preset=preset, n_train=4, n_test=2, seed=0, progress=False,
                          solve_fn=fake_scene_solve, batch=1, **split)
    out = tmp_path / "result.json"
    argv = [f"--dataset_dir={data}", "--n_train=3", "--n_val=1", "--n_test=2", f"--workdir={tmp_path / 'run'}",
            "--num_steps=4", "--batch_graphs=2", "--latent_size=16", "--message_passing_steps=2", "--log_every=2",
            "--val_every=2", "--ckpt_every=2", "--timing_repeats=2", f"--out={out}"]
    assert exp.main(argv) == 0
    res = json.loads(out.read_text())
    assert res["config"]["preset"] == preset and res["config"]["origin"] == origin
    assert res["training"]["step"] == 4 and len(res["test_designs"]) == 2
    assert np.isfinite(res["onepass"]["oled_objective_area_rel_error_pct_mean"])
    assert (tmp_path / "run" / "onepass_eval.json").is_file()
    with pytest.raises(ValueError, match="--origin does not apply: read from"):
        exp.main(argv + ["--origin=mesh", "--resume"])
