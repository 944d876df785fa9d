"""Run one scene in CalculiX and import the result as a trajectory (CalculiX: apt install calculix-ccx).

  python -m experiments.calculix --design 145.2,99.3 --preset cpu --out runs/ccx/opt1
  python -m experiments.calculix --scene pcmgn_jax/scenes/paper_panel.toml --design 100,100 --preset tiny --out DIR

Writes OUT/job.inp (the scene on the preset's mesh as an axisymmetric C3D8 wedge:
pcmgn_jax/data/exporters/calculix.py), runs ``ccx -i job`` there (OMP_NUM_THREADS=--threads; console output
in OUT/job.log), reads OUT/job.frd back (pcmgn_jax/data/calculix.py) and writes the trajectory OUT/trajectory
.xdmf/.h5/.json (source 'calculix', cropped to the preset's region of interest like the built-in solver's
output, so every metric, plot and baseline reads it) and OUT/summary.json (deck, settings, the contact force
per frame interval [N], ccx wall time). --stress recovered (default) gives the nodes the built-in solver's
von Mises rule applied to CalculiX's displacements; --stress frd CalculiX's own nodal stresses.
A missing ccx is an error naming the package. Run it under ``flock /tmp/heavy.lock nice -n 5`` on a shared box.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import ClassVar, Literal, Optional

from pcmgn_jax import cli

CALCULIX_PRESETS = ("tiny", "cpu", "paper")


@dataclass(frozen=True)
class CalculixArgs:
    """Run one design of a scene in CalculiX and import it."""
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"penalty_factor": (0, False), "increments_per_frame": (1, True), "threads": (1, True),
                              "frames": (0, True)}

    out: str
    """output folder: job.inp, job.frd, job.log, trajectory.{xdmf,h5,json}, summary.json"""
    design: Optional[str] = None
    """design thicknesses [µm], comma list (default: the scene's own)"""
    scene: Optional[str] = None
    """scene file (.toml / .json); default: the paper's panel"""
    preset: Literal[CALCULIX_PRESETS] = "tiny"
    """mesh preset (the project's own mesh)"""
    frames: Optional[int] = None
    """frames of output_dt to simulate (default: the scene's n_frames)"""
    penalty_factor: float = 1.0
    """contact penalty k_p = factor x E'/h [Pa/m], as the built-in solver's SolverSettings.penalty_factor (1: its
    production value)"""
    slave_faces: bool = True
    """the ball's surface faces as the contact's slave surface, so ccx's springs are as stiff as k_p says
    (--no_slave_faces: its nodes, which act ~10x stiffer; docs/results/calculix.md, Hertz)"""
    increments_per_frame: int = 2
    """largest implicit increment = output_dt / this (ccx's impact control shortens it in contact)"""
    alpha: float = 0.0
    """HHT alpha in [-1/3, 0] (0: no numerical damping)"""
    stress: Literal["recovered", "frd"] = "recovered"
    """nodal von Mises written into the trajectory"""
    threads: int = 1
    """OMP_NUM_THREADS for ccx"""
    ccx: Optional[str] = None
    """path of the ccx executable (default: ccx on PATH)"""


def main(argv=None) -> int:
    args = cli.parse(CalculixArgs, argv, description=__doc__, prog="python -m experiments.calculix")
    import dataclasses
    import json
    from pathlib import Path

    from pcmgn_jax.atomic import atomic_write_json, to_jsonable
    from pcmgn_jax.data.calculix import CalculixNotFoundError, CalculixRunError, run_scene
    from pcmgn_jax.data.exporters.calculix import CalculixSettings
    from pcmgn_jax.data.trajectory_io import write_trajectory
    from pcmgn_jax.scene import Scene, default_scene

    scene = Scene.load(args.scene) if args.scene else default_scene()
    if args.design:
        scene = scene.with_design(*(float(v) * 1e-6 for v in args.design.split(",")))
    if args.frames:
        scene = dataclasses.replace(scene, n_frames=int(args.frames))
    settings = CalculixSettings(increments_per_frame=args.increments_per_frame, alpha=args.alpha,
                                penalty_factor=args.penalty_factor, slave_faces=args.slave_faces)
    out = Path(args.out)
    try:
        traj, extra = run_scene(scene, args.preset, out, settings=settings, ccx=args.ccx, threads=args.threads,
                                stress=args.stress)
    except (CalculixNotFoundError, CalculixRunError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    digest = write_trajectory(traj, out / "trajectory")
    summary = {"command": cli.command_line("experiments.calculix", argv),
               "design_um": [d * 1e6 for d in scene.design], "preset": args.preset, "deck": extra["deck"],
               "settings": dataclasses.asdict(settings), "ccx_wall_time_s": extra["run"]["wall_time_s"],
               "force_N": extra["force_N"].tolist(), "output_dt": scene.output_dt, "trajectory_sha256": digest}
    atomic_write_json(out / "summary.json", to_jsonable(summary))
    print(json.dumps({k: summary[k] for k in ("design_um", "preset", "ccx_wall_time_s")}))
    print(f"wrote {out}/trajectory.xdmf/.h5/.json ({traj.n_nodes} nodes, {traj.n_frames} frames), peak contact "
          f"force {max(summary['force_N']):.2f} N")
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
