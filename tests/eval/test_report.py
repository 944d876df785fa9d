"""The run report (pcmgn_jax/eval/report.py, experiments/report.py): one self-contained HTML file from a run
directory's files, numbers and plots inside, nothing linked out, every string escaped; a clear error without
an evaluation. A fake run directory: no training, no jax computation."""
from __future__ import annotations

import json
import re
import struct
import zlib

import pytest

from pcmgn_jax.config import TrainConfig
from pcmgn_jax.eval import report


def _png(path, w=3, h=2):
    """A valid w x h grey PNG (no matplotlib needed)."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    raw = b"".join(b"\x00" + bytes([128] * w) for _ in range(h))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def _summary(pos, stress, area, node, pen, **extra):
    return {"position_mae_um": pos, "position_rmse_um": 2 * pos, "stress_mae_mpa": stress,
            "stress_rmse_mpa": 2 * stress, "penetration_max_um": pen, "penetration_mean_um": pen / 2,
            "oled_objective_rel_error_pct_mean": node, "oled_objective_rel_error_pct_max": 2 * node,
            "oled_objective_area_rel_error_pct_mean": area, "oled_objective_area_rel_error_pct_max": 2 * area,
            **extra}


def fake_metrics() -> dict:
    """metrics.json as pcmgn_jax.eval.evaluate writes it (its keys; two test designs)."""
    m = _summary(0.3241, 2.2997, 2.788, 3.976, 0.02985)
    m.update(per_frame_position_mae_um_mean=[0.0, 0.1, 0.2], per_frame_position_mae_um_std=[0.0, 0.01, 0.02],
             per_frame_stress_mae_mpa_mean=[0.0, 1.0, 2.0], per_frame_stress_mae_mpa_std=[0.0, 0.1, 0.2],
             per_part={"ball": {"position_mae_um": 0.1467, "stress_mae_mpa": 1.051},
                       "OLED": {"position_mae_um": 0.002812, "stress_mae_mpa": 0.2233}},
             penetration_frames=430, oled_objective_true_mpa=[2.17, 2.0987], oled_objective_pred_mpa=[2.172, 2.1031],
             oled_objective_area_true_mpa=[1.0394, 1.0291], oled_objective_area_pred_mpa=[1.0623, 1.091],
             penetration_max_um_truth=0.08334, penetration_mean_um_truth=0.0234, penetration_frames_truth=493,
             rollout_seconds_per_trajectory=5.249, n_test=2, n_frames=3, n_nodes=1144,
             n_nodes_per_trajectory=[1144, 1144], checkpoint="best", contact_projection=True, contact_capacity=288,
             phases=[{"drop": [0, 0], "contact": [1, 2], "rebound_in_contact": [None, None],
                      "separated": [None, None]}] * 2, window_has_all_phases=False)
    m["baselines"] = {
        "none": _summary(10.69, 36.08, 100.0, 100.0, 0.0, fit_seconds=1e-6, predict_seconds_per_trajectory=3e-4),
        "poly2": {"not_applicable": "poly2: needs <one shared mesh>"},
        "kriging": _summary(0.04093, 0.4077, 0.05943, 0.1277, 5.732, oled_objective_area_pred_mpa=[1.0391, 1.0294],
                            oled_objective_pred_mpa=[2.1711, 2.0969], fit_seconds=2.6,
                            predict_seconds_per_trajectory=0.006916,
                            warnings=["kriging: test_0001: OCA2 = 0.000148 outside the training range"]),
    }
    return m


@pytest.fixture
def fake_run(tmp_path):
    run = tmp_path / "run"
    (run / "eval").mkdir(parents=True)
    data = tmp_path / "data"
    data.mkdir()
    cfg = TrainConfig.from_preset("tiny", dataset_dir=str(data))
    cfg.save_json(run / "config.json")
    (run / "eval" / "metrics.json").write_text(json.dumps(fake_metrics()))
    _png(run / "eval" / "pred_truth_error.png")
    (run / "data.json").write_text(json.dumps({
        "format": "pcmgn_jax.run_data", "format_version": 1, "dataset_dir": str(data), "source": "generate",
        "train": [{"name": "train_0000", "sha256": "ab" * 32, "source": "solver", "n_nodes": 1144}],
        "val": [{"name": "<val&0>", "sha256": None, "source": "solver", "n_nodes": 1144}]}))
    (data / "manifest.json").write_text(json.dumps({
        "format": "pcmgn_jax.dataset", "format_version": 1, "preset": "tiny", "family": None,
        "design_layers": ["OCA1", "OCA2"],
        "scene": {"layers": [{"name": "OLED", "youngs": 5.15e9, "poisson": 0.3, "thickness": 3e-5, "density": 1450.0}]},
        "splits": {"test": {"origin": {"kind": "lhs", "seed": 0}, "trajectories": [
            {"name": "test_0001", "design_um": [60.0, 140.0]}, {"name": "test_0000", "design_um": [96.7, 121.8]}]}}}))
    (run / "metrics.jsonl").write_text('{"step": 100, "loss": 0.5}\n{"step": 200, "loss": 0.25}\n')
    return run


def test_report_holds_numbers_plots_config_and_provenance(fake_run):
    path = report.write_report(fake_run)
    assert path == fake_run / "report.html"
    html = path.read_text(encoding="utf-8")
    assert html.startswith("<!DOCTYPE html>") and html.rstrip().endswith("</html>")
    for number in ("0.3241", "2.3", "2.788 (5.576)", "10.69", "0.05943", "0.08334",   # MGN, none, kriging, truth
                   "0.2233", "0.002812",                                            # per part
                   "1.062", "1.039"):                                               # objective per design
        assert number in html, number
    assert "<b>0.04093</b>" in html                 # the column's best in bold (kriging's position MAE)
    assert '<img src="data:image/png;base64,' in html
    assert "test_0000: 96.7 / 121.8" in html        # the test designs in loading order (by name)
    assert "message_passing_steps" in html and "step 200, loss 0.25" in html
    assert "train_0000" in html and "abababababababab" in html and "lhs" in html
    # every string escaped, nothing linked out (a self-contained file)
    assert "&lt;val&amp;0&gt;" in html and "&lt;one shared mesh&gt;" in html and "<val&0>" not in html
    assert not re.search(r"""(?:src|href)\s*=\s*(?!["']?data:)""", html, flags=re.I)
    assert "http://" not in html and "https://" not in html
    assert "Design optimisation" not in html        # no optimise results in this run


def test_report_entry_point_with_optimise_results(fake_run, tmp_path, capsys):
    from experiments import report as entry
    opt = fake_run / "optimize"
    opt.mkdir()
    result = {"surrogate": "poly2", "method": "ga", "objective": "area_mean", "budget": {"pop": 100, "gens": 50},
              "optimum_um": [149.9998, 99.9995], "predicted_mpa": 0.97827, "search_seconds": 12.5, "n_evals": 3877,
              "dataset_best": {"design_um": [110.4, 135.4], "mpa": 1.01157}, "solver_mpa": 0.98010,
              "rel_error_pct": 0.1862, "beats_dataset_best": True, "command": "python -m experiments.optimize --x"}
    (opt / "poly2_ga.json").write_text(json.dumps(result))
    (opt / "mgn_ga.resume.json").write_text(json.dumps({"evals": []}))      # a GA in progress: not a result
    _png(opt / "poly2_ga.png")
    assert report.optimize_results(fake_run) == [opt / "poly2_ga.json"]
    out = tmp_path / "sub" / "r.html"
    assert entry.main(["--workdir", str(fake_run), "--out", str(out)]) == 0
    assert str(out) in capsys.readouterr().out
    html = out.read_text(encoding="utf-8")
    assert "Table 8" in html and "0.9783" in html and "0.9801" in html and "150.0 / 100.0" in html
    assert "100 × 50 (paper)" in html and "<code>python -m experiments.optimize --x</code>" in html
    assert html.count('<img src="data:image/png;base64,') == 2


def test_missing_metrics_names_the_file_and_the_command(tmp_path, capsys):
    from experiments import report as entry
    with pytest.raises(report.ReportError, match=r"eval/metrics\.json.*python -m experiments\.evaluate --workdir"):
        report.load_run(tmp_path)
    assert entry.main.__module__ == "experiments.report"
    from pcmgn_jax import cli
    assert cli.run(entry.main, ["--workdir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path}/eval/metrics.json" in err and "experiments.evaluate" in err
    assert not (tmp_path / "report.html").exists()
