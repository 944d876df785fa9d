"""The evaluation figures (pcmgn_jax/eval/plots.py) show the OLED layer: log colour scales for stress, an
OLED strip, the largest error marked, the objective over time from the one objective definition."""
from __future__ import annotations

import matplotlib

matplotlib.use("Agg")  # files only, as the entry points choose

import numpy as np
import pytest
from matplotlib.colors import LogNorm

from fixtures.helpers import make_synthetic_trajectory
from pcmgn_jax import metrics
from pcmgn_jax.eval import plots


@pytest.fixture
def oled_traj():
    """The synthetic trajectory with its CG layer named OLED (the figures find the layer by name)."""
    t = make_synthetic_trajectory(1.0)
    t.meta["part_names"] = ["ball", "OLED", "PLATE"]
    return t


def test_compare_frames_log_scale_oled_strip_and_largest_error(oled_traj, tmp_path, monkeypatch):
    t = oled_traj
    pred_s = np.asarray(t.von_mises) * 1.1
    pred_s[:, 7] += 3e6                          # one node 3 MPa off: the circle must find it
    norms = []
    real = plots._mesh
    monkeypatch.setattr(plots, "_mesh", lambda *a, **k: norms.append(k.get("norm")) or real(*a, **k))
    out = tmp_path / "pred_truth_error.png"
    frames = [3, t.n_frames - 1]
    info = plots.compare_frames(out, t.points, t.cells, t.displacement, t.displacement, pred_s,
                                np.asarray(t.von_mises), frames, node_part=t.node_part, part_names=t.meta["part_names"])
    assert out.stat().st_size > 1000
    assert len(norms) == 3 * len(frames) and all(isinstance(n, LogNorm) for n in norms)
    assert info["stress_norm"] == "log"
    vmax = max(pred_s[3].max(), t.von_mises[3].max()) * 1e-6
    assert norms[0].vmax == pytest.approx(vmax) and norms[0].vmin == pytest.approx(vmax / 10 ** plots.STRESS_DECADES)
    worst = info["max_error"][1]
    assert worst["node"] == 7 and worst["frame"] == frames[1] and worst["mpa"] == pytest.approx(3.0, rel=1e-6)
    assert worst["part"] == t.meta["part_names"][t.node_part[7]]
    x, y = (t.points[7] + t.displacement[frames[1], 7]) * 1e3
    assert (worst["x_mm"], worst["y_mm"]) == pytest.approx((x, y))
    # without part names: three rows, no strip, still log scales
    plots.compare_frames(out, t.points, t.cells, t.displacement, t.displacement, pred_s, np.asarray(t.von_mises), [3])


def test_stress_norm_shows_a_small_layer_beside_a_large_one():
    norm = plots.stress_norm(700.0)
    assert 0.05 < float(norm(1.0)) < 0.5 < float(norm(100.0))   # 1 MPa is not black beside 700 MPa
    assert float(norm(0.0)) == 0.0 and float(norm(700.0)) == 1.0


def test_objective_vs_time_uses_the_objective_definition(oled_traj, tmp_path):
    t = oled_traj
    pred = np.asarray(t.von_mises) * 0.9
    out = tmp_path / "oled_objective_vs_time.png"
    curves = plots.objective_vs_time(out, t, pred)
    assert out.stat().st_size > 1000
    for r in (metrics.DEFAULT_OBJECTIVE, "node_mean"):
        c = curves[r]
        assert c["pred_mpa"].shape == (t.n_frames,)
        # the objective is the time mean of the per-frame curve, and both are metrics.oled_objective_of's
        assert c["objective_true_mpa"] == pytest.approx(float(metrics.oled_objective_of(t, reading=r)))
        assert np.mean(c["true_mpa"]) == pytest.approx(c["objective_true_mpa"])
        assert c["pred_mpa"] == pytest.approx(0.9 * c["true_mpa"])
