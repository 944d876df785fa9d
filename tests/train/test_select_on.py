"""select_on='objective': the best checkpoint is chosen on the validation rollouts' area-mean OLED objective error,
the evaluation's figure (pcmgn_jax/train/loop.py)."""
import json

import numpy as np
import pytest

from fixtures.helpers import synthetic_scene_trajectory, tiny_config
from pcmgn_jax.config import TrainConfig
from pcmgn_jax.mgn import checkpoint
from pcmgn_jax.scene import default_scene
from pcmgn_jax.train import loop


@pytest.fixture(scope="module")
def scene_trajs():
    scene = default_scene()
    return [synthetic_scene_trajectory(scene, {"name": f"s{i}"}, n_frames=5, preset="tiny") for i in range(3)]


def test_the_best_checkpoint_is_the_validation_objectives_minimum(scene_trajs, tmp_path):
    cfg = tiny_config(select_on="objective", num_steps=80, val_every=20, log_every=20)
    res = loop.train(cfg, tmp_path, train_trajs=scene_trajs[:2], val_trajs=scene_trajs[2:])
    vals = [r for r in map(json.loads, (tmp_path / "metrics.jsonl").read_text().splitlines())
            if "val_objective_error_pct" in r]
    assert [r["step"] for r in vals] == list(range(20, 81, 20))
    assert all(np.isfinite(r["val_position_mae_um"]) for r in vals)   # both figures logged
    errs = np.array([r["val_objective_error_pct"] for r in vals])
    assert np.all(np.isfinite(errs)) and np.ptp(errs) > 0
    best = vals[int(np.argmin(errs))]
    best_dir = tmp_path / "checkpoints" / "best"
    _, meta = checkpoint.read_meta(best_dir, checkpoint.steps(best_dir)[-1])
    assert meta["best_step"] == best["step"] and meta["best_val"] == pytest.approx(errs.min())
    assert res["best_val"] == pytest.approx(errs.min()) and res["select_on"] == "objective"
    assert loop.best_line(res).startswith("best validation objective error")


def test_the_validation_objective_is_the_evaluations_figure(scene_trajs):
    """The same rollout scored by the evaluation's one scoring of an objective prediction."""
    from pcmgn_jax.eval.baselines import objective_scores
    from pcmgn_jax.surrogates.objective import objective_of_fields
    from pcmgn_jax.train.setup import prepare
    from pcmgn_jax.train.step import eval_params, init_state

    cfg = tiny_config()
    setup = prepare(cfg, scene_trajs[:2])
    params = eval_params(cfg, init_state(setup.spec, loop.init_params(setup, scene_trajs[0], 0)))
    got = loop.validation_scores(setup, params, scene_trajs, objective=loop.objective_readings(scene_trajs))
    _, vm = loop.rollout_frames(setup, params, scene_trajs)
    want = objective_scores(scene_trajs, {"area_mean": objective_of_fields(scene_trajs, vm)})
    assert got["val_objective_error_pct"] == pytest.approx(want["oled_objective_area_rel_error_pct_mean"], rel=1e-9)
    assert set(loop.validation_scores(setup, params, scene_trajs)) == {"val_position_mae_um"}


def test_a_validation_set_without_an_oled_and_an_unknown_choice_are_refused(tiny_trajs, tmp_path):
    with pytest.raises(ValueError, match="select_on='objective' .*validation trajectory.* needs a part named 'OLED'"):
        loop.train(tiny_config(select_on="objective"), tmp_path, train_trajs=tiny_trajs[:2], val_trajs=tiny_trajs[2:])
    assert not (tmp_path / "metrics.jsonl").exists()
    with pytest.raises(ValueError, match="select_on"):
        TrainConfig().replace(select_on="loss")
