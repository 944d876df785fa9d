"""Write a scene as a CalculiX (``ccx``) input deck on the project's own mesh (axisymmetric scenes).

What is mapped (Abaqus-style keywords, SI units: m, kg, s, Pa, like the project):

* the geometry as a thin wedge of ``C3D8`` bricks: the 2D quad mesh (:func:`pcmgn_jax.sim.mesh.build_mesh`)
  revolved by +-``wedge_deg``/2 about the symmetry axis, which becomes the global z axis (the project's
  height y). ccx's own ``CAX4`` is expanded into exactly such a wedge internally, but ccx 2.20 then loses
  the kinetic energy of ``*INITIAL CONDITIONS, TYPE=VELOCITY`` (Dhondtguido/CalculiX issue 63: the velocity
  reaches the expanded nodes only through a surface, and the energy bookkeeping reads ~1e-36 J), and its
  implicit impact control, which checks the energy balance at every contact change, then refuses every
  increment. Node ``i + 1`` = mesh node ``i`` on the +half-angle face, node ``N + i + 1`` its copy on the
  -half-angle face (the axis nodes exist once: those bricks collapse an edge); element ``e + 1`` = cell ``e``.
  Full 2x2x2 integration, the counterpart of the built-in Q4's 2x2 (``*TRANSFORM, TYPE=C`` gives the
  off-axis nodes (r, theta, z) dofs; u_theta = 0 on both faces is the axisymmetry).
* one ``*ELSET`` per part named after the part (upper case: ``BALL``, ``CG``, ``OCA1`` ...), a ``*MATERIAL``
  of the same name (``*ELASTIC`` E, nu; ``*DENSITY`` rho) and a ``*SOLID SECTION``. The layers share their
  interface nodes in the project's mesh (bonded), so no ``*TIE`` is needed.
* node sets ``BALLN`` (the ball), ``FIXED`` (the clamped plate bottom: all dofs), ``AXIS`` (x = 0: u_x = u_y = 0)
  and ``OFFAXIS`` (the rest: u_theta = 0).
* the scene's contact pair (ball -> top layer): node-to-surface penalty contact, the ball's lower surface
  nodes (``SBALL``, the solver's slaves, without the pole: see :func:`inp_text`) against the top layer's
  upper brick faces (``MTOP``, face S5), ``PRESSURE-OVERCLOSURE=LINEAR`` with the built-in solver's penalty
  k_p = ``penalty_factor`` x E'/h [Pa/m] (:func:`contact_penalty`), frictionless.
* ``*INITIAL CONDITIONS, TYPE=VELOCITY``: v_z = -``ball.velocity`` on ``BALLN``; everything else at rest.
* one ``*STEP`` of implicit ``*DYNAMIC`` (HHT, ``alpha`` = 0 by default: Newmark's average acceleration, no
  numerical damping) over the scene's window ``n_frames x output_dt``, the largest increment ``output_dt /
  increments_per_frame`` (ccx's impact control shortens it in contact), and ``*NODE FILE`` U, V and
  ``*EL FILE`` S at the frame times (``*TIME POINTS``), so the .frd holds the scene's frames.

No gravity, no damping, small strains (``NLGEOM`` off), as in the built-in solver (docs/design.md §2-3).
:func:`static_inp_text` is the same model under a static pressure instead of the impact (the ball held, no
contact): the panel's stiffness alone, e.g. to compare ``C3D8`` with ``C3D8I``, which ccx does not allow in
``*DYNAMIC`` (its incompatible modes carry no mass). :func:`write_inp` writes the deck atomically and returns a
summary; :func:`parse_inp` reads a deck this module writes back (for the round-trip tests).
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pcmgn_jax.atomic import atomic_write_text
from pcmgn_jax.data.exporters.common import ExportError, export_errors
from pcmgn_jax.scene import Scene
from pcmgn_jax.sim.mesh import Mesh, MeshSpec, build_mesh

__all__ = ["CCX_COUNTERPART", "CalculixSettings", "ELEMENT_TYPE", "ELEMENTS", "calculix_mesh", "contact_penalty",
           "inp_text", "parse_inp", "set_name", "static_inp_text", "write_inp"]

#: the scene's analysis -> CalculiX element type (4-node, full integration)
ELEMENT_TYPE = "C3D8"
#: the element types a deck may use (CalculixSettings.element)
ELEMENTS = ("C3D8", "C3D8I")
#: the built-in solver's 2D element (pcmgn_jax.sim.fem.Q4_ELEMENTS) each ccx element is the 3D counterpart of; a
#: ccx displacement field is read into stresses with it
CCX_COUNTERPART = {"C3D8": "q4", "C3D8I": "q4i"}
_PER_LINE = 8


@dataclass(frozen=True)
class CalculixSettings:
    """How the deck integrates in time and models contact.

    increments_per_frame: fixed increments per output frame (implicit: the step is output_dt / this)
    alpha:           HHT-alpha in [-1/3, 0] (0: Newmark average acceleration, no numerical damping)
    explicit:        ``*DYNAMIC, EXPLICIT`` (central differences, lumped mass; needs a tiny step: set
                     ``increments_per_frame`` so output_dt / it is below the stable step)
    penalty_factor:  contact penalty k_p = factor x E'/h [Pa/m] (the built-in solver's rule)
    wedge_deg:       the wedge's angle [deg] (ccx revolves its own axisymmetric elements by 2 deg)
    element:         ``C3D8`` (full 2x2x2 integration, the built-in Q4's counterpart) or ``C3D8I`` (with
                     incompatible bending modes: no shear locking in long, thin elements)
    min_increment_ratio: smallest increment / largest: ccx's impact control shrinks the increment at
                     contact changes and then grows it by 1 % per increment, so a floor keeps a rebound from
                     leaving it at 1e-10 s for thousands of increments
    tension:         ccx's sigma_inf [Pa], the small tension node-to-surface springs keep at large
                     clearance (must be > 0; ccx's own default is MPa-sized, ~1 N over the contact zone)
    slave_faces:     the slave surface as the ball's surface faces (``TYPE=ELEMENT``, the default) instead
                     of its nodes (``TYPE=NODE``): ccx then takes each slave node's area from those faces
                     alone; from a node set it takes the node's external faces, which in a wedge include the
                     flat side faces, and its springs act ~10x stiffer than k_p (docs/results/calculix.md).
                     The first cross-check tables were made with node slaves (``--no_slave_faces`` redoes them)
    """

    increments_per_frame: int = 8
    alpha: float = 0.0
    explicit: bool = False
    penalty_factor: float = 1.0
    tension: float = 1e4
    wedge_deg: float = 2.0
    min_increment_ratio: float = 0.05
    element: str = ELEMENT_TYPE
    slave_faces: bool = True

    def __post_init__(self) -> None:
        if self.element not in ELEMENTS:
            raise ValueError(f"calculix: element must be one of {ELEMENTS}, got {self.element!r}")
        if int(self.increments_per_frame) < 1:
            raise ValueError(f"calculix: increments_per_frame must be >= 1, got {self.increments_per_frame!r}")
        if not -1.0 / 3.0 - 1e-12 <= self.alpha <= 0.0:
            raise ValueError(f"calculix: alpha must lie in [-1/3, 0], got {self.alpha!r}")
        if not (math.isfinite(self.penalty_factor) and self.penalty_factor > 0):
            raise ValueError(f"calculix: penalty_factor must be > 0, got {self.penalty_factor!r}")


def set_name(part: str) -> str:
    """The ELSET / MATERIAL name of a part: upper case, CalculiX's own case (it upper-cases names)."""
    name = part.upper()
    if not re.fullmatch(r"[A-Z][A-Z0-9_]{0,79}", name):
        raise ExportError(f"calculix: part name {part!r} is not a valid set name (letters, digits, _)")
    return name


def contact_penalty(scene: Scene, mesh: Mesh, penalty_factor: float) -> float:
    """The built-in solver's penalty k_p = factor x E'/h [Pa/m] (:func:`pcmgn_jax.sim.prepare.prepare`):
    E' the plane-strain modulus of the softer of the ball and the top layer, h the first master segment."""
    top, ball = scene.layers[0], scene.ball
    e_soft = min(top.youngs / (1 - top.poisson**2), ball.youngs / (1 - ball.poisson**2))
    xm = np.sort(mesh.points[mesh.panel_top, 0])
    return float(penalty_factor * e_soft / (xm[1] - xm[0]))


def calculix_mesh(scene: Scene, preset: str | MeshSpec) -> Mesh:
    """The project's full (uncropped) mesh of ``scene`` at ``preset``: what the deck holds."""
    return build_mesh(scene, preset)


def _num(value: float) -> str:
    """A float as CalculiX reads it: at most 20 characters per field (its Fortran reads), 14 significant
    digits (the round-trip error is ~1e-14 relative)."""
    return f"{float(value):.13e}"


def _id_lines(ids) -> list[str]:
    ids = [int(i) for i in ids]
    return [", ".join(str(i) for i in ids[k:k + _PER_LINE]) for k in range(0, len(ids), _PER_LINE)]


def _wedge(mesh: Mesh, half_angle: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """3D nodes (M, 3) [m] and C3D8 connectivity (E, 8) (0-based) of the mesh revolved by +-half_angle
    [rad] about the y (height) axis, which becomes the global z axis: 2D (x, y) -> (x cos t, x sin t, y).
    Node i is at +half_angle, node N + i at -half_angle (axis nodes, x = 0, exist once: ``minus[i] = i``).
    Element corners 1-4 are the quad at +half_angle (counter-clockwise in (x, y), so its normal points to
    the -half_angle face), 5-8 the same quad at -half_angle; an axis edge collapses (a degenerate brick)."""
    n = mesh.n_nodes
    x, y = mesh.points[:, 0], mesh.points[:, 1]
    on_axis = x <= 0.0
    minus = np.where(on_axis, np.arange(n), n + np.arange(n))
    c, sn = math.cos(half_angle), math.sin(half_angle)
    plus_xyz = np.stack([x * c, x * sn, y], axis=1)
    minus_xyz = np.stack([x * c, -x * sn, y], axis=1)
    nodes = np.concatenate([plus_xyz, minus_xyz])
    cells = np.concatenate([mesh.cells, minus[mesh.cells]], axis=1)
    return nodes, cells, minus


def _top_faces(mesh: Mesh, top_part: int) -> list[tuple[int, str]]:
    """(element number, face label) of the top layer's upper faces: cells whose 2D edge 3-4 lies on the panel
    top, i.e. brick face S5 (corners 3-7-8-4)."""
    top = np.zeros(mesh.n_nodes, bool)
    top[mesh.panel_top] = True
    rows = [int(e) for e in np.flatnonzero(mesh.cell_part == top_part)
            if top[mesh.cells[e, 2]] and top[mesh.cells[e, 3]]]
    if not rows:
        raise ExportError("calculix: found no upper faces of the top layer (cells with nodes 3-4 on the panel top)")
    return [(e + 1, "S5") for e in rows]


def _ball_faces(mesh: Mesh) -> list[tuple[int, str]]:
    """(element number, face label) of the ball's surface faces: 2D edges of ball cells with both nodes on the
    ball's (contact) surface and off the axis; quad edge k-(k+1) is brick face S(k+3) (1-2: S3 ... 4-1: S6)."""
    on = np.zeros(mesh.n_nodes, bool)
    on[np.asarray(mesh.ball_surface)] = True
    on &= mesh.points[:, 0] > 0
    rows = [(int(e) + 1, f"S{k + 3}") for e in np.flatnonzero(mesh.cell_part == 0) for k in range(4)
            if on[mesh.cells[e, k]] and on[mesh.cells[e, (k + 1) % 4]]]
    if not rows:
        raise ExportError("calculix: found no ball surface faces (cells with two surface nodes off the axis)")
    return rows


def inp_text(scene: Scene, mesh: Mesh, settings: CalculixSettings = CalculixSettings(), *,
             title: str = "pcmgn_jax scene") -> str:
    """The .inp deck of ``scene`` on ``mesh`` (see the module docstring for what is mapped)."""
    if scene.analysis != "axisymmetric":
        raise ExportError(f"calculix: only the axisymmetric analysis is mapped (a wedge); the scene is "
                          f"{scene.analysis!r}")
    names = list(scene.part_names)
    if len(scene.contact_pairs) != 1 or scene.contact_pairs[0][0] != names[0] \
            or scene.contact_pairs[0][1] != names[1]:
        raise ExportError(f"calculix: only the contact pair (ball, top layer) is mapped; the scene has "
                          f"{scene.contact_pairs}")
    props = [(scene.ball.youngs, scene.ball.poisson, scene.ball.density)] + \
        [(lay.youngs, lay.poisson, lay.density) for lay in scene.layers]
    nodes, bricks, minus = _wedge(mesh, math.radians(settings.wedge_deg) / 2)
    n = mesh.n_nodes
    used = np.unique(bricks)
    out = [f"** {title}", "** written by pcmgn_jax.data.exporters.calculix; units SI (m, kg, s, Pa)",
           f"** axisymmetric {settings.wedge_deg} deg wedge of C3D8 about the global z axis (= the project's y);",
           "** node i+1 = mesh node i on the +half-angle face, node N+i+1 its copy on the -half-angle face,",
           f"** N = {n}; element e+1 = cell e", "*NODE"]
    out += [f"{i + 1}, {_num(a)}, {_num(b)}, {_num(c)}" for i, (a, b, c) in zip(used.tolist(), nodes[used].tolist())]
    for pid, name in enumerate(names):
        cells = np.flatnonzero(mesh.cell_part == pid)
        if not len(cells):
            raise ExportError(f"calculix: part {name!r} has no cells in the mesh")
        out.append(f"*ELEMENT, TYPE={settings.element}, ELSET={set_name(name)}")
        out += [f"{e + 1}, " + ", ".join(str(int(k) + 1) for k in bricks[e]) for e in cells]
    both = lambda ids: np.unique(np.concatenate([ids, minus[ids]]))   # noqa: E731
    ball_nodes = both(np.unique(mesh.cells[mesh.cell_part == 0]))
    clamped = both(np.flatnonzero(mesh.fixed.all(axis=1)))
    on_axis = np.flatnonzero(mesh.points[:, 0] <= 0.0)
    off_axis = np.setdiff1d(used, on_axis)
    for sname, ids in (("BALLN", ball_nodes), ("FIXED", clamped), ("AXIS", on_axis), ("OFFAXIS", off_axis)):
        if len(ids):
            out += [f"*NSET, NSET={sname}"] + _id_lines(ids + 1)
    # the pole (x = 0) is no slave: its collapsed brick gives it ~zero mass, and ccx's impact control then
    # limits the increment to that node's contact period (1e-10 s); its ring area is < 0.5 % of the contact's
    surf2d = np.asarray(mesh.ball_surface)
    surface = both(surf2d[mesh.points[surf2d, 0] > 0])
    out += ["*NSET, NSET=SBALLN"] + _id_lines(surface + 1)
    if settings.slave_faces:   # the faces between two slave nodes (so not the pole's: see above)
        out += ["*SURFACE, NAME=SBALL, TYPE=ELEMENT"] + [f"{e}, {f}" for e, f in _ball_faces(mesh)]
    else:
        out += ["*SURFACE, NAME=SBALL, TYPE=NODE", "SBALLN"]
    out += ["*SURFACE, NAME=MTOP, TYPE=ELEMENT"] + [f"{e}, {f}" for e, f in _top_faces(mesh, 1)]
    for name, (e, nu, rho) in zip(names, props):
        out += [f"*MATERIAL, NAME={set_name(name)}", "*ELASTIC", f"{_num(e)}, {_num(nu)}",
                "*DENSITY", f"{_num(rho)}", f"*SOLID SECTION, ELSET={set_name(name)}, MATERIAL={set_name(name)}"]
    k_p = contact_penalty(scene, mesh, settings.penalty_factor)
    out += ["*SURFACE INTERACTION, NAME=IMPACT", "*SURFACE BEHAVIOR, PRESSURE-OVERCLOSURE=LINEAR",
            f"{_num(k_p)}, {_num(settings.tension)}",
            "*CONTACT PAIR, INTERACTION=IMPACT, TYPE=NODE TO SURFACE", "SBALL, MTOP"]
    # cylindrical dofs (r, theta, z) off the axis: theta = 0 on both faces is the axisymmetry
    out += ["*TRANSFORM, NSET=OFFAXIS, TYPE=C", "0., 0., 0., 0., 0., 1."]
    out += ["*BOUNDARY", "OFFAXIS, 2, 2", "AXIS, 1, 2"]
    if len(clamped):
        out.append("FIXED, 1, 3")
    out += ["*INITIAL CONDITIONS, TYPE=VELOCITY", f"BALLN, 3, {_num(-scene.ball.velocity)}"]
    n_inc = int(settings.increments_per_frame)
    dt = scene.output_dt / n_inc
    window = scene.output_dt * scene.n_frames
    # ccx's impact rules cut the increment at contact changes, so the increment is the largest one allowed
    # (not DIRECT) and the frames are time points
    dyn = f"*DYNAMIC, ALPHA={_num(settings.alpha)}" + (", EXPLICIT" if settings.explicit else "")
    out += ["*TIME POINTS, NAME=FRAMES, GENERATE",
            f"{_num(scene.output_dt)}, {_num(window)}, {_num(scene.output_dt)}",
            f"*STEP, INC={100 * n_inc * scene.n_frames}", dyn,
            f"{_num(dt)}, {_num(window)}, {_num(dt * settings.min_increment_ratio)}, {_num(dt)}",
            "*NODE FILE, TIME POINTS=FRAMES, GLOBAL=YES", "U, V", "*EL FILE, TIME POINTS=FRAMES, GLOBAL=YES", "S",
            "*END STEP"]
    return "\n".join(out) + "\n"


def static_inp_text(scene: Scene, mesh: Mesh, settings: CalculixSettings = CalculixSettings(), *,
                    pressure: float, radius: float, title: str = "pcmgn_jax scene, static pressure") -> str:
    """The deck of :func:`inp_text` with the impact replaced by a static load: the ball's nodes held (all dofs;
    it touches nothing), no contact pair and no initial velocity, one linear ``*STATIC`` step with the uniform
    ``pressure`` [Pa] (> 0 pushes down) on the top layer's upper faces that lie wholly within ``radius`` [m] of
    the axis (``*DLOAD`` P5), and ``*NODE FILE`` U, ``*EL FILE`` S. The model part (nodes, elements, sets,
    materials, the axisymmetry's ``*TRANSFORM`` and ``*BOUNDARY``) is :func:`inp_text`'s own, line for line."""
    if not (math.isfinite(pressure) and math.isfinite(radius) and radius > 0):
        raise ExportError(f"calculix: static load needs a finite pressure and a radius > 0, got {pressure!r}, "
                          f"{radius!r}")
    lines = inp_text(scene, mesh, settings, title=title).splitlines()
    model = lines[:lines.index("*SURFACE INTERACTION, NAME=IMPACT")]
    constraints = lines[lines.index(next(ln for ln in lines if ln.startswith("*TRANSFORM"))):
                        lines.index("*INITIAL CONDITIONS, TYPE=VELOCITY")]
    faces = [(e, f) for e, f in _top_faces(mesh, 1) if mesh.points[mesh.cells[e - 1], 0].max() <= radius * (1 + 1e-9)]
    if not faces:
        raise ExportError(f"calculix: no top-layer face lies within {radius!r} m of the axis")
    return "\n".join(model + constraints + ["*BOUNDARY", "BALLN, 1, 3", "*STEP", "*STATIC", "*DLOAD"]
                     + [f"{e}, P{f[1]}, {_num(pressure)}" for e, f in faces]
                     + ["*NODE FILE", "U", "*EL FILE", "S", "*END STEP"]) + "\n"


def write_inp(path: str | os.PathLike, scene: Scene, preset: str | MeshSpec,
              settings: CalculixSettings = CalculixSettings()) -> dict[str, Any]:
    """Write ``scene`` on the preset's mesh as ``path`` (.inp, atomically); return a summary: node counts (the
    2D mesh's and the wedge's), the element count, part names, the penalty [Pa/m], the increment [s] and the frame
    count."""
    mesh = calculix_mesh(scene, preset)
    text = inp_text(scene, mesh, settings, title=f"pcmgn_jax scene, design {scene.design}")
    with export_errors(path):
        atomic_write_text(path, text, parents=True)
    n_axis = int(np.count_nonzero(mesh.points[:, 0] <= 0.0))
    return {"inp": str(path), "n_nodes": mesh.n_nodes, "n_nodes_wedge": 2 * mesh.n_nodes - n_axis,
            "n_elements": int(len(mesh.cells)),
            "part_names": list(scene.part_names), "element_type": settings.element,
            "penalty_Pa_per_m": contact_penalty(scene, mesh, settings.penalty_factor),
            "increment_s": scene.output_dt / settings.increments_per_frame,
            "n_frames": scene.n_frames, "output_dt": scene.output_dt}


def parse_inp(path: str | os.PathLike) -> dict[str, Any]:
    """Read back what :func:`write_inp` writes: {"nodes": (N, 2) [m], "elements": {number: (4,) node
    numbers}, "elsets": {name: [element numbers]}, "nsets": {name: [node numbers]}, "materials":
    {name: {"elastic": (E, nu), "density": rho}}, "keywords": [keyword lines]}. ExportError naming the
    file and line on anything it cannot read."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as err:
        raise ExportError(f"{path}: cannot read: {err.strerror or err}") from None
    nodes: dict[int, tuple[float, float]] = {}
    elements: dict[int, tuple[int, ...]] = {}
    elsets: dict[str, list[int]] = {}
    nsets: dict[str, list[int]] = {}
    materials: dict[str, dict[str, Any]] = {}
    keywords: list[str] = []
    block, params, material = "", {}, None
    for no, raw in enumerate(lines, 1):
        line = raw.strip()
        if not line or line.startswith("**"):
            continue
        if line.startswith("*"):
            parts = [p.strip() for p in line.split(",")]
            block = parts[0].upper()
            params = dict((p.split("=", 1) + [""])[:2] for p in parts[1:])
            params = {k.strip().upper(): v.strip().upper() for k, v in params.items()}
            keywords.append(line)
            if block == "*MATERIAL":
                material = params.get("NAME")
                materials[material] = {}
            continue
        try:
            vals = [v.strip() for v in line.split(",") if v.strip()]
            if block == "*NODE":
                nodes[int(vals[0])] = (float(vals[1]), float(vals[2]), float(vals[3]))
            elif block == "*ELEMENT":
                elements[int(vals[0])] = tuple(int(v) for v in vals[1:])
                elsets.setdefault(params.get("ELSET", ""), []).append(int(vals[0]))
            elif block == "*NSET":
                nsets.setdefault(params["NSET"], []).extend(int(v) for v in vals)
            elif block == "*ELASTIC":
                materials[material]["elastic"] = (float(vals[0]), float(vals[1]))
            elif block == "*DENSITY":
                materials[material]["density"] = float(vals[0])
        except (ValueError, IndexError, KeyError, TypeError) as err:
            raise ExportError(f"{path}:{no}: cannot read {block} data line {line!r} ({err})") from None
    if not nodes:
        raise ExportError(f"{path}: no *NODE data")
    return {"nodes": nodes, "elements": elements, "elsets": elsets,
            "nsets": nsets, "materials": materials, "keywords": keywords}
