"""ParaView comparison export."""
from __future__ import annotations

import json

import meshio
import numpy as np
import pytest

from fixtures.synthetic import synthetic_trajectory
from pcmgn_jax.data.trajectory_io import write_trajectory
from pcmgn_jax.eval.export import export_comparison


def test_export_fields_and_errors(tmp_path):
    truth = synthetic_trajectory()
    pred_d = truth.displacement + 1e-6
    pred_vm = truth.von_mises + 2e6
    path = export_comparison(truth, truth.positions + 1e-6, pred_vm, tmp_path / "cmp")
    with meshio.xdmf.TimeSeriesReader(path) as r:
        r.read_points_cells()
        t, pd, cd = r.read_data(1)
    assert t == truth.times[1]
    for key in ("displacement_true", "displacement_pred", "displacement_error"):
        assert pd[key].shape == (truth.n_nodes, 3)
    np.testing.assert_allclose(pd["displacement_pred"][:, :2], pred_d[1], rtol=0, atol=1e-18)
    np.testing.assert_allclose(pd["position_abs_error"], np.sqrt(2) * 1e-6, rtol=1e-6)
    np.testing.assert_allclose(pd["von_mises_abs_error"], 2e6, rtol=1e-9)
    summary = json.loads((tmp_path / "cmp.json").read_text())
    assert summary["position_mae_um"] == pytest.approx(1.0)  # per component (pcmgn_jax.metrics), 1 µm in x and y
    assert summary["stress_mae_mpa"] == pytest.approx(2.0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cmp.h5", "cmp.json", "cmp.xdmf"]
    with pytest.raises(ValueError, match=r"shape \(4, 18, 1\), expected \(4, 18, 2\)"):
        export_comparison(truth, pred_d[..., :1], pred_vm, tmp_path / "x", pred_kind="displacement")
    bad = pred_vm.copy()
    bad[2, 5] = np.inf
    with pytest.raises(ValueError, match=r"pred_von_mises has a non-finite value at index \[2, 5\]"):
        export_comparison(truth, pred_d, bad, tmp_path / "x", pred_kind="displacement")
    assert not any(p.name.startswith("x") for p in tmp_path.iterdir())


def test_export_cli(tmp_path, capsys):
    from experiments.export import main

    truth = synthetic_trajectory()
    write_trajectory(truth, tmp_path / "traj")
    np.savez(tmp_path / "pred.npz", displacement=truth.displacement * 1.1, von_mises=truth.von_mises)
    assert main(["--trajectory", str(tmp_path / "traj"), "--pred", str(tmp_path / "pred.npz"),
                 "--out", str(tmp_path / "o" / "cmp")]) == 0
    assert (tmp_path / "o" / "cmp.xdmf").exists()
    assert main(["--trajectory", str(tmp_path / "traj"), "--workdir", str(tmp_path / "no_run")]) == 2
    err = capsys.readouterr().err
    assert "no_run: no such run folder" in err and "experiments.train --workdir" in err


def test_export_cli_with_trained_model(tiny_run, tiny_trajs, tmp_path):
    """--workdir rolls the trained model out and writes truth, prediction and error side by side."""
    import meshio

    from experiments.export import main

    _, workdir, _ = tiny_run
    write_trajectory(tiny_trajs[-1], tmp_path / "traj")
    assert main(["--trajectory", str(tmp_path / "traj"), "--workdir", str(workdir),
                 "--out", str(tmp_path / "cmp")]) == 0
    with meshio.xdmf.TimeSeriesReader(str(tmp_path / "cmp.xdmf")) as reader:
        reader.read_points_cells()
        _, point_data, _ = reader.read_data(1)
    assert {"displacement_true", "displacement_pred"} <= set(point_data)
