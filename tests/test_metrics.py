"""pcmgn_jax.metrics: every metric against hand-computed values (one definition each)."""
import numpy as np
import pytest

from pcmgn_jax import metrics


def test_field_metrics_hand_computed():
    true_u = np.zeros((1, 3, 2, 2))
    pred_u = true_u.copy()
    pred_u[0, 0] = 9.0  # frame 0 is the given initial state: never counted
    pred_u[0, 1, 0] = [1e-6, -3e-6]   # |err| 1 and 3 µm
    pred_u[0, 2, 1] = [2e-6, 0.0]     # 2 and 0 µm; node 0 / frame 2 and node 1 / frame 1 exact
    true_vm = np.zeros((1, 3, 2))
    pred_vm = true_vm.copy()
    pred_vm[0, 1] = [1e6, 3e6]
    m = metrics.field_metrics(pred_u, pred_vm, true_u, true_vm)
    # 8 per-component errors over frames 1..2: 1, 3, 0, 0 | 0, 0, 2, 0 µm
    assert m["position_mae_um"] == pytest.approx(6 / 8)
    assert m["position_rmse_um"] == pytest.approx(np.sqrt(14 / 8))
    assert m["stress_mae_mpa"] == pytest.approx(4 / 4)
    assert m["stress_rmse_mpa"] == pytest.approx(np.sqrt(10 / 4))
    assert m["per_frame_position_mae_um_mean"] == pytest.approx([0.0, 1.0, 0.5])
    assert metrics.position_mae_um(pred_u, true_u) == m["position_mae_um"]
    with pytest.raises(ValueError, match="shape"):
        metrics.field_metrics(pred_u[:, :2], pred_vm, true_u, true_vm)


def test_per_part_metrics_hand_computed():
    true_u = np.zeros((1, 3, 2, 2))
    pred_u = true_u.copy()
    pred_u[0, 1, 0] = [1e-6, -3e-6]   # node 0 (part 0): 1, 3 | 0, 0 µm over frames 1..2
    pred_u[0, 2, 1] = [2e-6, 0.0]     # node 1 (part 1): 0, 0 | 2, 0 µm
    true_vm = np.zeros((1, 3, 2))
    pred_vm = true_vm.copy()
    pred_vm[0, 1] = [1e6, 3e6]
    m = metrics.per_part_metrics(pred_u, pred_vm, true_u, true_vm, [np.array([0, 1])], ["ball", "CG", "OLED"])
    assert m == {"ball": {"position_mae_um": pytest.approx(1.0), "stress_mae_mpa": pytest.approx(0.5)},
                 "CG": {"position_mae_um": pytest.approx(0.5), "stress_mae_mpa": pytest.approx(1.5)}}


def test_penetration_pooled_over_trajectories():
    panel = np.array([[0.0, 0.0], [1.0, 0.0]])
    a = metrics.penetration_stats(np.array([[[0.5, -1e-6]], [[0.5, 1e-6]]]), panel)      # 1 µm in frame 0
    b = metrics.penetration_stats(np.array([[[0.2, -3e-6], [0.4, -5e-6]]]), panel)       # 3 and 5 µm
    assert a["max_um"] == pytest.approx(1.0) and a["n_penetrating"] == 1 and a["frames_with_penetration"] == 1
    s = metrics.penetration_summary([a, b])
    assert s["penetration_max_um"] == pytest.approx(5.0)
    assert s["penetration_mean_um"] == pytest.approx(3.0)  # (1 + 3 + 5) / 3, not the mean of 1 and 4
    assert s["penetration_frames"] == 2
    assert metrics.penetration_summary([metrics.penetration_stats(np.array([[[0.5, 1e-6]]]), panel)]) == {
        "penetration_max_um": 0.0, "penetration_mean_um": 0.0, "penetration_frames": 0}


def test_oled_objective_node_mean_hand_computed():
    oled = 5
    node_part = np.array([oled, oled, oled, 1])  # OLED at x = 1, 2 mm (in), 4 mm (out); CG
    points = np.array([[1e-3, 0.0], [2e-3, 0.0], [4e-3, 0.0], [1e-3, 1e-3]])
    vm = np.array([[[1e6, 3e6, 100e6, 100e6], [3e6, 5e6, 100e6, 100e6]]])  # (B=1, T=2, N=4) Pa
    w = metrics.objective_weights(points, None, None, node_part, part=oled, reading="node_mean")
    obj = metrics.oled_objective(vm, w, reading="node_mean")
    assert obj == pytest.approx([3.0])  # mean of 1, 3, 3, 5 MPa
    assert metrics.relative_error_pct(obj * 1.5, obj) == pytest.approx([50.0])
    with pytest.raises(ValueError, match="no node of part 9"):
        metrics.objective_weights(points, None, None, node_part, part=9, reading="node_mean")
    assert metrics.relative_error_pct(np.array([1.0]), np.array([0.0]))[0] > 1e12  # guarded, finite
