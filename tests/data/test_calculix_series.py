"""The mesh-refinement series' pieces (issue 43): sim.mesh.refined, sim.mesh.named_spec's
PRESET@F names, and eval.calculix_check.section_weights (the area mean over a fixed section)."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from pcmgn_jax import metrics
from pcmgn_jax.eval.calculix_check import section_weights
from pcmgn_jax.scene import default_scene
from pcmgn_jax.sim.mesh import build_mesh, graded_coords, mesh_spec, named_spec, refined, roi


def test_refined_halves_sizes_and_doubles_counts():
    base, fine = mesh_spec("cpu"), refined("cpu", 2)
    assert fine.h_contact == pytest.approx(base.h_contact / 2) and fine.h_layer == pytest.approx(base.h_layer / 2)
    assert {k: 2 * v for k, v in base.layer_elems.items()} == dict(fine.layer_elems)
    assert fine.roi_x == base.roi_x and fine.fine_radius == base.fine_radius
    # the graded zone too: about twice the elements between 0.5 and 2.5 mm, each about half as large
    xs, xf = (graded_coords(8e-3, s.h_contact, s.fine_radius, s.growth) for s in (base, fine))
    n_base, n_fine = (np.count_nonzero((x > 0.5e-3) & (x < 2.5e-3)) for x in (xs, xf))
    assert 1.8 <= n_fine / n_base <= 2.2
    coarse = refined("cpu", 0.5)
    assert coarse.layer_elems["OLED"] == 1 and coarse.layer_elems["OCA1"] == 2   # rounded up, at least 1
    assert refined("cpu", 1) == base
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="refinement factor"):
            refined("cpu", bad)


def test_named_spec_names():
    assert named_spec("cpu") == "cpu"
    assert named_spec("paper@2") == refined("paper", 2)
    assert named_spec("cpu_fine").layer_elems["OLED"] == 4
    with pytest.raises(ValueError, match="cpu@x"):
        named_spec("cpu@x")
    base, full = mesh_spec("cpu"), refined("cpu", 2)
    far, layers, plate = (named_spec(f"cpu@2:{z}") for z in ("far", "layers", "plate"))
    assert far.growth == full.growth and dict(far.layer_elems) == dict(base.layer_elems)
    assert layers.growth == base.growth and layers.layer_elems["OLED"] == 4 and layers.layer_elems["PLATE"] == 6
    assert plate.layer_elems["PLATE"] == 12 and plate.layer_elems["OLED"] == 2
    assert plate.bottom_growth == full.bottom_growth and plate.h_contact == base.h_contact
    with pytest.raises(ValueError, match="zone must be far, layers, plate"):
        named_spec("cpu@2:ball")
    both = named_spec("cpu@0.5:layers+far")   # zones joined: each zone's change, the rest the preset's
    assert both.growth == refined("cpu", 0.5).growth and both.layer_elems["OLED"] == 1
    assert both.layer_elems["PLATE"] == 6 and both.h_contact == base.h_contact
    assert mesh_spec("cpu@0.5:layers+far") == both     # the library resolves the names


@pytest.fixture(scope="module")
def roi_mesh():
    scene = default_scene()
    sub, _ = roi(build_mesh(scene, "cpu"), "cpu")
    return sub, scene.part_names.index("OLED")


def test_section_weights_on_a_node_equal_the_area_mean(roi_mesh):
    sub, oled = roi_mesh
    w = metrics.objective_weights(sub.points, sub.cells, sub.cell_part, sub.node_part, part=oled)
    x_end = sub.points[w > 0, 0].max()
    assert np.allclose(section_weights(sub.points, sub.cells, sub.cell_part, part=oled, x_end=x_end), w,
                       rtol=0, atol=1e-14)


def test_section_weights_integrate_a_linear_field_exactly(roi_mesh):
    sub, oled = roi_mesh
    cut = sub.points[:, 0][(sub.points[:, 0] > 1.8e-3) & (sub.points[:, 0] < 2.2e-3)]
    x_end = 0.5 * (np.unique(cut)[0] + np.unique(cut)[1])     # inside a cell, not on a node
    w = section_weights(sub.points, sub.cells, sub.cell_part, part=oled, x_end=x_end)
    assert w.sum() == pytest.approx(1.0) and np.all(w >= 0)
    assert w @ sub.points[:, 0] == pytest.approx(x_end / 2, rel=1e-12)   # mean of x over [0, x_end]
    assert np.all(w[sub.points[:, 0] > x_end + 1e-3] == 0)


def test_section_weights_errors(roi_mesh):
    sub, oled = roi_mesh
    with pytest.raises(ValueError, match="short of x_end"):
        section_weights(sub.points, sub.cells, sub.cell_part, part=oled, x_end=10e-3)
    with pytest.raises(ValueError, match="not axis-aligned rectangles"):
        section_weights(sub.points, sub.cells, sub.cell_part, part=0, x_end=1e-4)   # the ball's cells
    with pytest.raises(ValueError, match="no cell of part"):
        section_weights(sub.points, sub.cells, sub.cell_part, part=99, x_end=1e-3)


def test_calculix_element_choice():
    import dataclasses

    from pcmgn_jax.data.exporters.calculix import CalculixSettings, calculix_mesh, inp_text

    scene = dataclasses.replace(default_scene(), n_frames=2)
    deck = inp_text(scene, calculix_mesh(scene, "tiny"), CalculixSettings(element="C3D8I"))
    assert deck.count("*ELEMENT, TYPE=C3D8I,") == len(scene.part_names) and "TYPE=C3D8," not in deck
    with pytest.raises(ValueError, match="element must be one of"):
        CalculixSettings(element="CAX4")


@pytest.mark.skipif(shutil.which("ccx") is None, reason="CalculiX 'ccx' not installed (apt install calculix-ccx)")
def test_c3d8i_deck_runs_and_reads_back(tmp_path):
    """ccx accepts the C3D8I wedge (collapsed axis bricks included) and its .frd reads back as a trajectory."""
    import dataclasses

    from pcmgn_jax.data.calculix import frd_trajectory, run_ccx
    from pcmgn_jax.data.exporters.calculix import CalculixSettings, write_inp

    scene = dataclasses.replace(default_scene(), n_frames=2)
    write_inp(tmp_path / "job.inp", scene, "tiny", CalculixSettings(element="C3D8I", increments_per_frame=2))
    run_ccx(tmp_path / "job.inp", timeout=120)
    traj, extra = frd_trajectory(tmp_path / "job.frd", scene, "tiny")
    assert traj.displacement.shape[0] == 3 and np.isfinite(traj.displacement).all()
    ball = traj.node_part == 0
    # free flight before contact: the ball moved down by v t, the panel is at rest
    assert traj.displacement[-1, ball, 1].mean() == pytest.approx(-scene.ball.velocity * 2 * scene.output_dt, rel=1e-3)
    assert np.abs(traj.displacement[-1, ~ball]).max() < 1e-12


def test_static_deck_keeps_the_model_and_replaces_the_impact():
    import math

    from pcmgn_jax.data.exporters.calculix import ExportError, calculix_mesh, inp_text, static_inp_text

    scene = default_scene()
    mesh = calculix_mesh(scene, "tiny")
    dynamic, static = inp_text(scene, mesh).splitlines(), static_inp_text(scene, mesh, pressure=1e6, radius=2.5e-4)
    model = dynamic[:dynamic.index("*SURFACE INTERACTION, NAME=IMPACT")]
    assert static.splitlines()[1:len(model)] == model[1:]   # the same model, line for line (the title differs)
    for gone in ("*CONTACT PAIR", "*INITIAL CONDITIONS", "*DYNAMIC"):
        assert gone not in static
    assert "*STATIC" in static and "BALLN, 1, 3" in static and "*TRANSFORM, NSET=OFFAXIS, TYPE=C" in static
    top = np.sort(mesh.points[mesh.panel_top, 0])
    loads = [ln for ln in static.splitlines() if ", P5, " in ln]
    assert len(loads) == np.count_nonzero(top[1:] <= 2.5e-4 * (1 + 1e-9))   # faces wholly inside the radius
    assert all(math.isclose(float(ln.split(",")[2]), 1e6) for ln in loads)
    for bad in (0.0, float("nan")):
        with pytest.raises(ExportError, match="radius > 0"):
            static_inp_text(scene, mesh, pressure=1e6, radius=bad)
    with pytest.raises(ExportError, match="no top-layer face"):
        static_inp_text(scene, mesh, pressure=1e6, radius=top[1] / 2)


@pytest.mark.skipif(shutil.which("ccx") is None, reason="CalculiX 'ccx' not installed (apt install calculix-ccx)")
def test_static_deck_runs_c3d8i_is_never_stiffer(tmp_path):
    """The static deck runs in ccx and reads back; incompatible modes only add deformation modes, so C3D8I's
    deflection under the same load is at least C3D8's (on `tiny`, with its long far-field elements, more). The
    built-in solver's static solve of the same model (pcmgn_jax.sim.static) with each ccx element's 2D
    counterpart agrees: q4 with C3D8, q4i with C3D8I, within 1 % on the deflection and 2 % on the OLED stress."""
    from pcmgn_jax.data.calculix import run_ccx, static_fields
    from pcmgn_jax.data.exporters.calculix import CCX_COUNTERPART, CalculixSettings, calculix_mesh, static_inp_text
    from pcmgn_jax.sim.static import static_pressure

    scene = default_scene()
    mesh = calculix_mesh(scene, "tiny")
    centre = {}
    for element in ("C3D8", "C3D8I"):
        (tmp_path / element).mkdir()
        (tmp_path / element / "job.inp").write_text(
            static_inp_text(scene, mesh, CalculixSettings(element=element), pressure=1e8, radius=2.5e-4))
        u, vm = static_fields(run_ccx(tmp_path / element / "job.inp", timeout=60)["frd"], scene, "tiny",
                              ccx_element=element)
        assert np.isfinite(u).all() and np.isfinite(vm).all() and vm.min() >= 0
        ball = np.unique(mesh.cells[mesh.cell_part == 0])
        assert np.abs(u[mesh.fixed.all(axis=1)]).max() == 0.0 and np.abs(u[ball]).max() == 0.0   # clamped, held
        top = np.asarray(mesh.panel_top)
        centre_node = top[np.argmin(mesh.points[top, 0])]
        centre[element] = -u[centre_node, 1]
        assert centre[element] > 0   # pushed down
        _, ub, vmb = static_pressure(scene, "tiny", pressure=1e8, radius=2.5e-4, element=CCX_COUNTERPART[element])
        assert -ub[centre_node, 1] == pytest.approx(centre[element], rel=0.01)
        oled = mesh.node_part == list(scene.part_names).index("OLED")
        assert vmb[oled].mean() == pytest.approx(vm[oled].mean(), rel=0.02)
    assert centre["C3D8I"] > 1.05 * centre["C3D8"]


def test_slave_faces_option_lists_the_ball_surface_faces(tmp_path):
    import dataclasses

    from pcmgn_jax.data.exporters.calculix import CalculixSettings, inp_text, parse_inp

    scene = dataclasses.replace(default_scene(), n_frames=2)
    mesh = build_mesh(scene, "tiny")
    nodes_deck = inp_text(scene, mesh, CalculixSettings(slave_faces=False))
    assert "*SURFACE, NAME=SBALL, TYPE=NODE\nSBALLN\n" in nodes_deck   # --no_slave_faces: the node set
    assert inp_text(scene, mesh) == inp_text(scene, mesh, CalculixSettings(slave_faces=True))   # faces: the default
    (tmp_path / "job.inp").write_text(inp_text(scene, mesh))
    deck = parse_inp(tmp_path / "job.inp")
    lines = (tmp_path / "job.inp").read_text().splitlines()
    start = lines.index("*SURFACE, NAME=SBALL, TYPE=ELEMENT") + 1
    faces = [ln.split(", ") for ln in lines[start:lines.index("*SURFACE, NAME=MTOP, TYPE=ELEMENT")]]
    corners = {"S3": (0, 4, 5, 1), "S4": (1, 5, 6, 2), "S5": (2, 6, 7, 3), "S6": (3, 7, 4, 0)}   # C3D8 faces
    slaves = set(deck["nsets"]["SBALLN"])
    surface_off_axis = [i for i in mesh.ball_surface if mesh.points[i, 0] > 0]
    assert len(faces) == len(surface_off_axis) - 1      # one face between two neighbouring slave nodes
    for elem, label in faces:
        nodes = deck["elements"][int(elem)]
        assert int(elem) in deck["elsets"]["BALL"]
        assert {nodes[k] for k in corners[label]} <= slaves   # every corner of the face is a slave node


@pytest.mark.slow
def test_the_q4i_series_converges_where_q4_locks(tmp_path):
    """The refinement series' claim in small (python -m experiments.mesh_series): on cpu and cpu@2 the default
    q4i element reads the fixed-section OLED objective within 2 % and the peak force within 1 % of each other;
    q4 moves by more than 4 % / 3 % between the same meshes (it locks in bending)."""
    from experiments.mesh_series import SeriesArgs, row

    args = SeriesArgs(out=str(tmp_path / "ms"))
    got = {(m, e): row(args, m, "builtin", e) for m in ("cpu", "cpu@2") for e in ("q4i", "q4")}

    def change(e, key):
        return abs(got[("cpu", e)][key] / got[("cpu@2", e)][key] - 1)

    assert change("q4i", "objective_fixed_section_mpa") < 0.02
    assert change("q4i", "peak_force_N") < 0.01
    assert change("q4", "objective_fixed_section_mpa") > 0.04
    assert change("q4", "peak_force_N") > 0.03
