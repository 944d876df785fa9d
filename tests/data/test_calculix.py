"""CalculiX export, run and import (pcmgn_jax/data/exporters/calculix.py, data/importers/frd.py,
data/calculix.py). The ccx round trip skips, saying why, when Debian's calculix-ccx is not installed."""
from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest

from pcmgn_jax.data import calculix as ccx
from pcmgn_jax.data.exporters.calculix import (
    CalculixSettings,
    calculix_mesh,
    contact_penalty,
    parse_inp,
    write_inp,
)
from pcmgn_jax.data.importers.errors import InputFileError
from pcmgn_jax.data.importers.frd import read_frd
from pcmgn_jax.scene import default_scene

HAVE_CCX = shutil.which("ccx") is not None
needs_ccx = pytest.mark.skipif(not HAVE_CCX, reason="CalculiX 'ccx' not installed (apt install calculix-ccx)")


def _scene(n_frames=2):
    return dataclasses.replace(default_scene(), n_frames=n_frames)


def test_inp_round_trip_tiny_scene(tmp_path):
    scene = _scene()
    summary = write_inp(tmp_path / "job.inp", scene, "tiny")
    deck = parse_inp(tmp_path / "job.inp")
    mesh = calculix_mesh(scene, "tiny")
    n, on_axis = mesh.n_nodes, int(np.count_nonzero(mesh.points[:, 0] <= 0))
    # a wedge: every node on both faces, the axis nodes once
    assert len(deck["nodes"]) == 2 * n - on_axis
    assert summary["n_nodes"] == n and len(deck["elements"]) == len(mesh.cells)
    # node i + 1 is mesh node i on the +half-angle face: radius and height come back
    xyz = np.array([deck["nodes"][i + 1] for i in range(n)])
    np.testing.assert_allclose(np.hypot(xyz[:, 0], xyz[:, 1]), mesh.points[:, 0], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(xyz[:, 2], mesh.points[:, 1], rtol=1e-12)
    # one element set and material per part, with the scene's properties
    names = [p.upper() for p in scene.part_names]
    assert set(names) <= set(deck["elsets"]) and set(names) <= set(deck["materials"])
    for pid, name in enumerate(names):
        assert len(deck["elsets"][name]) == int(np.count_nonzero(mesh.cell_part == pid))
    glass = scene.layers[0]
    assert deck["materials"]["CG"]["elastic"] == pytest.approx((glass.youngs, glass.poisson), rel=1e-12)
    assert deck["materials"]["BALL"]["density"] == pytest.approx(scene.ball.density, rel=1e-12)
    # boundary sets: the clamped bottom on both faces, the axis once, the ball's nodes
    bottom = np.flatnonzero(mesh.fixed.all(axis=1))
    assert len(deck["nsets"]["FIXED"]) == 2 * len(bottom) - int(np.count_nonzero(mesh.points[bottom, 0] <= 0))
    assert sorted(deck["nsets"]["AXIS"]) == sorted((np.flatnonzero(mesh.points[:, 0] <= 0) + 1).tolist())
    assert len(deck["nsets"]["BALLN"]) > 0
    keys = " ".join(deck["keywords"]).upper()
    for kw in ("*CONTACT PAIR", "PRESSURE-OVERCLOSURE=LINEAR", "*INITIAL CONDITIONS, TYPE=VELOCITY", "*DYNAMIC",
               "*NODE FILE", "*EL FILE", "*BOUNDARY"):
        assert kw in keys, kw
    assert summary["penalty_Pa_per_m"] == pytest.approx(contact_penalty(scene, mesh, 1.0))


def test_settings_and_analysis_are_checked(tmp_path):
    with pytest.raises(ValueError, match="alpha"):
        CalculixSettings(alpha=0.2)
    with pytest.raises(ValueError, match="axisymmetric"):
        write_inp(tmp_path / "x.inp", dataclasses.replace(_scene(), analysis="plane_strain"), "tiny")


def test_missing_ccx_is_a_named_error(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(ccx.CalculixNotFoundError, match="apt install calculix-ccx"):
        ccx.find_ccx()
    with pytest.raises(ccx.CalculixNotFoundError):
        ccx.run_scene(_scene(), "tiny", tmp_path / "run")
    assert not (tmp_path / "run").exists()   # nothing written before the check


FRD = """    1C
    1UMAT    1BALL
    2C                             2                                     1
 -1         1 0.00000E+00 0.00000E+00 0.00000E+00
 -1         2 1.00000E-03-2.50000E-04 5.00000E-04
 -3
    1PSTEP                         1           1           1
  100CL  101 4.00000E-06           2                     1    1           1
 -4  DISP        4    1
 -5  D1          1    2    1    0
 -5  D2          1    2    2    0
 -5  D3          1    2    3    0
 -5  ALL         1    2    0    0    1ALL
 -1         1-1.00000E-06-2.00000E-06 0.00000E+00
 -1         2 3.00000E-07-4.00000E-06 1.00000E-09
 -3
 9999
"""


def test_frd_reader_fixed_width_records(tmp_path):
    path = tmp_path / "r.frd"
    path.write_text(FRD)
    res = read_frd(path)
    np.testing.assert_array_equal(res.node_ids, [1, 2])
    np.testing.assert_allclose(res.nodes[1], [1e-3, -2.5e-4, 5e-4])   # no blank before a negative value
    assert res.components["DISP"] == ["D1", "D2", "D3"] and res.materials == {1: "BALL"}
    np.testing.assert_allclose(res.times, [4e-6])
    np.testing.assert_allclose(res.results["DISP"][0], [[-1e-6, -2e-6, 0.0], [3e-7, -4e-6, 1e-9]])
    path.write_text(FRD.replace(" -3\n 9999\n", ""))
    with pytest.raises(InputFileError, match="not closed"):
        read_frd(path)
    path.write_text("garbage\n")
    with pytest.raises(InputFileError, match="not a CalculiX"):
        read_frd(path)


@needs_ccx
def test_ccx_round_trip_tiny_scene(tmp_path):
    """.inp -> ccx -> .frd -> trajectory on the tiny mesh, two frames of free flight (8 us, before contact):
    finite fields in SI, the ball displaced by -v t and moving at -v, the panel at rest."""
    scene = _scene(n_frames=2)
    traj, extra = ccx.run_scene(scene, "tiny", tmp_path / "run", settings=CalculixSettings(increments_per_frame=2))
    traj.validate("test")
    assert traj.meta["source"] == "calculix" and traj.meta["units"]["length"] == "m"
    assert traj.n_frames == 3 and np.allclose(traj.times, [0.0, 4e-6, 8e-6])
    ball = traj.node_part == 0
    v = scene.ball.velocity
    np.testing.assert_allclose(traj.displacement[2, ball, 1], -v * 8e-6, rtol=1e-4)
    np.testing.assert_allclose(traj.velocity[1:, ball, 1], -v, rtol=1e-4)
    assert np.abs(traj.displacement[:, ~ball]).max() < 1e-12
    assert np.abs(extra["force_N"]).max() < 1e-6 * scene.ball.velocity   # no contact yet: momentum kept
    for reading in ccx.STRESS_READINGS:
        assert np.isfinite(extra["von_mises_full"][reading]).all()


def test_contact_window_and_compare_read_a_force_history():
    from pcmgn_jax.eval.calculix_check import compare, contact_window

    dt = 4e-6
    t = (np.arange(100) + 0.5) * dt
    force = np.where((t > 16e-6) & (t < 316e-6), 28.0 * np.sin(np.pi * (t - 16e-6) / 300e-6), 0.0)
    w = contact_window(force, dt)
    assert w["contact_start_s"] == pytest.approx(16e-6) and w["contact_end_s"] == pytest.approx(316e-6)
    assert w["contact_duration_s"] == pytest.approx(300e-6) and w["peak_force_N"] == pytest.approx(28.0, rel=1e-3)
    still_on = contact_window(np.ones(10), dt)
    assert np.isnan(still_on["contact_end_s"])   # no separation inside the window
    c = compare({"peak_force_N": 29.4}, {"peak_force_N": 28.0})
    assert c["peak_force_N"]["rel_diff"] == pytest.approx(0.05)
