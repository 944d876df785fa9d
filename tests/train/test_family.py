"""Scene families and training on varied meshes (issue 12).

Fast: the family meshes change with the design; a training union of graphs of different meshes gives
each graph the loss and gradient it has alone (padding and the other graphs change nothing, noise and
penetration term on); the jitted training chunk compiles once for unions of other meshes in its bucket.
Slow: the ``family_tiny`` dataset through the solver, then ``experiments.train`` and
``experiments.evaluate`` end to end.
"""
import json

import jax
import numpy as np
import pytest

from fixtures.helpers import CompileCounter, drop_last_column, make_synthetic_trajectory, one_union, tiny_config
from pcmgn_jax.scene import default_scene, with_parameters
from pcmgn_jax.sim.mesh import build_mesh, roi, with_spec
from pcmgn_jax.train.loop import init_params
from pcmgn_jax.train.sampling import gather_unions, pair_table, sample_ids
from pcmgn_jax.train.setup import prepare
from pcmgn_jax.train.step import loss_fn, train_chunk


def test_family_meshes_follow_the_scene_parameters():
    base = default_scene()
    n = lambda params: roi(build_mesh(with_parameters(base, params), "family_tiny"), "family_tiny")[0].n_nodes  # noqa
    ref = n({})
    for params in ({"OCA1": 50e-6}, {"OCA2": 150e-6}, {"POL": 110e-6}, {"ball.radius": 4e-3}):
        assert n(params) != ref, params  # each parameter changes the node count
    with pytest.raises(ValueError, match="scene parameter 'ball.mass'"):
        with_parameters(base, {"ball.mass": 1.0})
    with pytest.raises(ValueError, match="fixed element count"):  # the single-topology presets refuse it
        build_mesh(base, with_spec("family_tiny", thickness_elems=False))


@pytest.fixture(scope="module")
def mixed():
    """Three synthetic trajectories of two meshes (the second without its last column) and their setup
    (noise on, penetration term on, the ball radius as a node input)."""
    trajs = [make_synthetic_trajectory(0.9), drop_last_column(make_synthetic_trajectory(1.1)),
             make_synthetic_trajectory(1.0)]
    cfg = tiny_config(lambda_pen=10.0, poly_ball=2, poly_panel=3, noise_rel=1.0, noise_parts="all",
                      batch_graphs=2, scene_features="ball_radius")
    setup = prepare(cfg, trajs)
    return trajs, setup, init_params(setup, trajs[0], 0)


@pytest.mark.slow  # ~70 s: keeps the default suite under 10 minutes on 2 cores
def test_padding_and_other_graphs_change_no_loss_or_gradient(mixed):
    trajs, setup, params = mixed
    assert len({t.n_nodes for t in trajs}) == 2
    key = jax.random.PRNGKey(3)
    pair_a, pair_b = (0, 4), (1, 6)

    def graph_loss(batch, g):
        return jax.value_and_grad(lambda p: loss_fn(p, setup.spec, setup.stats, batch, key)[1]["loss_graph"][g])(params)

    alone = one_union(setup, trajs, [pair_a], graph_ids=[7])
    together = one_union(setup, trajs, [pair_b, pair_a], graph_ids=[5, 7])  # a is graph 1, other offsets
    assert together.graph.points.shape[0] > alone.graph.points.shape[0]  # more padding too
    (la, ga), (lt, gt) = graph_loss(alone, 0), graph_loss(together, 1)
    assert float(la) > 0 and abs(float(la) - float(lt)) <= 1e-5 * float(la)
    flat = lambda t: np.concatenate([np.ravel(np.asarray(x)) for x in jax.tree.leaves(t)])  # noqa: E731
    assert np.abs(flat(ga) - flat(gt)).max() <= 1e-4 * np.abs(flat(ga)).max()
    # the union's loss is the mean over its real graphs (padding slots excluded)
    total, aux = loss_fn(params, setup.spec, setup.stats, together, key)
    lb = graph_loss(one_union(setup, trajs, [pair_b], graph_ids=[5]), 0)[0]
    assert abs(float(total) - 0.5 * (float(la) + float(lb))) <= 1e-5 * float(total)
    assert float(aux["loss_graph"][2]) == 0.0  # the padding graph


@pytest.mark.slow  # ~20 s (the default suite's 10-minute budget)
def test_union_chunk_compiles_once_across_meshes(mixed):
    trajs, setup, _ = mixed
    from pcmgn_jax.train.step import init_state
    state = init_state(setup.spec, init_params(setup, trajs[0], 0))
    table = pair_table(trajs)
    form, K = setup.spec.sim.formulation, 2

    def batch(step):
        ids = sample_ids(0, step, K, 2, setup.n_pairs)
        return ids, gather_unions(form, trajs, setup.graphs, table, ids, dt=setup.spec.sim.dt, sizes=setup.sizes)

    state, _ = train_chunk(setup.spec, state, setup.stats, batch(0)[1], jax.random.PRNGKey(0))  # warm-up
    seen = set()
    with CompileCounter("train_chunk") as c:
        for step in range(2, 30, 2):
            ids, b = batch(step)
            seen |= {tuple(sorted({int(table[i][0]) for i in row})) for row in ids}
            state, m = train_chunk(setup.spec, state, setup.stats, b, jax.random.PRNGKey(0))
        jax.block_until_ready(m)
    assert {(0, 1), (1, 2)} & seen and c.count == 0, (seen, c.count)  # unions of both meshes, no recompile


@pytest.mark.slow
def test_family_tiny_generation_has_differing_meshes(family_tiny):
    from pcmgn_jax.data.layout import load_manifest
    from pcmgn_jax.data.splits import load_directory
    man = load_manifest(family_tiny)
    assert man["preset"] == "family_tiny" and [p[0] for p in man["family"]["parameters"]] == \
        ["ball.radius", "ball.velocity", "OCA1", "OCA2", "POL"]
    entries = man["splits"]["train"]["trajectories"] + man["splits"]["test"]["trajectories"]
    trajs = load_directory(family_tiny / "train") + load_directory(family_tiny / "test")
    assert len(trajs) == len(entries) == 7
    assert len({t.n_nodes for t in trajs}) >= 3
    for t, e in zip(trajs, entries):
        assert t.meta["scene_params"] == e["scene_params"]
        assert t.meta["scene"]["ball"]["radius"] == e["scene_params"]["ball.radius"]
        assert t.meta["scene"]["ball"]["velocity"] == e["scene_params"]["ball.velocity"]
        assert 4e-3 <= e["scene_params"]["ball.radius"] <= 6e-3 and 30e-6 <= t.meta["design"]["POL"] <= 70e-6


@pytest.mark.slow
def test_family_tiny_train_and_evaluate_end_to_end(family_tiny, tmp_path):
    from experiments import evaluate, train
    run = tmp_path / "run"
    assert train.main(["--preset", "family_tiny", f"--dataset_dir={family_tiny}", f"--workdir={run}",
                       "--num_steps=20", "--val_every=20", "--progress=False"]) == 0
    assert evaluate.main(["--workdir", str(run), "--mgn_spread"]) == 0
    m = json.loads((run / "eval" / "metrics.json").read_text())
    assert m["n_test"] == 2 and len(set(m["n_nodes_per_trajectory"])) == 2
    s = m["mgn_spread"]     # a ± beside each prediction, from the model's residuals on its 4 training scenes
    assert len(s["std_mpa"]) == 2 and all(np.isfinite(s["std_mpa"])) and "training scenes (4)" in s["source"]
    assert np.isfinite(m["position_mae_um"]) and np.isfinite(m["oled_objective_area_rel_error_pct_mean"])
    b = m["baselines"]
    for kind in ("none", "nearest"):
        assert np.isfinite(b[kind]["position_mae_um"]), b[kind]
    for kind in ("poly2", "rbf"):
        assert "shared topology" in b[kind]["not_applicable"]


@pytest.mark.slow  # ~90 s: the solver for 5 tiny scenes, then 20 training steps
def test_train_on_a_generated_dataset_at_its_manifest_sizes(tmp_path):
    """generate --n_train 3 --n_test 1 (3 + the preset's 1 validation design), then train with no size flags."""
    from experiments import generate, train
    data, run = tmp_path / "data", tmp_path / "run"
    assert generate.main(["--preset", "family_tiny", "--n_train", "3", "--n_test", "1", "--out", str(data),
                          "--no_progress"]) == 0
    man = json.loads((data / "manifest.json").read_text())
    assert len(man["splits"]["train"]["trajectories"]) == 4 and len(man["splits"]["test"]["trajectories"]) == 1
    assert train.main(["--preset", "family_tiny", f"--dataset_dir={data}", f"--workdir={run}", "--num_steps=20",
                       "--val_every=20", "--no_progress"]) == 0
    cfg = json.loads((run / "config.json").read_text())
    assert (cfg["n_train"], cfg["n_val"], cfg["n_test"]) == (3, 1, 1)
    rec = json.loads((run / "data.json").read_text())
    assert len(rec["train"]) == 3 and len(rec["val"]) == 1
