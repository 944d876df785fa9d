"""The design objective (DESIGN §8) in evaluation: mean OLED von Mises at x < 3 mm over all frames."""
from types import SimpleNamespace

import numpy as np
import pytest

from pcmgn_jax.eval.evaluate import oled_objective
from pcmgn_jax.scene import default_scene


def test_oled_objective_hand_computed():
    scene = default_scene()
    oled = scene.part_names.index("OLED")
    # nodes: OLED at x = 1 mm and 2 mm (in), OLED at 4 mm (out), CG at 1 mm (other part)
    ref = SimpleNamespace(node_part=np.array([oled, oled, oled, 1]),
                          points=np.array([[1e-3, 0.0], [2e-3, 0.0], [4e-3, 0.0], [1e-3, 1e-3]]))
    vm = np.array([[[1e6, 3e6, 100e6, 100e6], [3e6, 5e6, 100e6, 100e6]]])  # (B=1, T=2, N=4) Pa
    truth = [SimpleNamespace(von_mises=vm[0])]
    out = oled_objective(scene, ref, None, vm * 1.5, truth)
    assert out["oled_objective_true_mpa"] == pytest.approx([3.0])   # mean of 1, 3, 3, 5 MPa
    assert out["oled_objective_pred_mpa"] == pytest.approx([4.5])
    assert out["oled_objective_rel_error_pct_mean"] == pytest.approx(50.0)


def test_oled_objective_absent_layer_is_empty():
    scene = default_scene()
    ref = SimpleNamespace(node_part=np.zeros(3, int), points=np.zeros((3, 2)))
    assert oled_objective(scene, ref, None, np.zeros((1, 2, 3)), [SimpleNamespace(von_mises=np.zeros((2, 3)))],
                          layer="NOPE") == {}
