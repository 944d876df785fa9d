"""The built-in solver against CalculiX on the same mesh: Hertz, then the paper's panel (issue 43).

  python -m experiments.calculix_check --preset tiny --out results/calculix   # needs ccx (apt install calculix-ccx)

For each design (default: the paper's two optima, physics-constrained (145.207, 99.322) µm and vanilla
(100.364, 149.635) µm, and the corner (50, 100) µm of the design box) the scene runs in CalculiX
(pcmgn_jax/data/calculix.py; OUT/runs/<label>/job.{inp,frd,log}, reused when the deck is unchanged) and in the
built-in solver with the same contact penalty, on the same mesh; pcmgn_jax/eval/calculix_check.py reads both
the same way: contact force per 4 µs interval, contact duration, peak cover-glass von Mises, the OLED
objective's readings, and the fields at three frames. --hertz adds the Hertz case (sim/hertz.py's scene and
mesh) against theory (expensive in ccx; not part of the default run). The built-in solver also runs at its production
penalty (factor 1) to show how much the penalty moves each figure. Writes OUT/check.json and OUT/check.md. Heavy: run it
under ``flock /tmp/heavy.lock nice -n 5``.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import ClassVar, Literal

from pcmgn_jax import cli

DESIGNS = "145.207,99.322;100.364,149.635;50,100"
LABELS = "pc_optimum,vanilla_optimum,corner_50_100"


@dataclass(frozen=True)
class CheckArgs:
    """Cross-check the built-in solver against CalculiX."""
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"penalty_factor": (0, False), "increments_per_frame": (1, True), "frames": (0, True),
                              "hertz_penalty_factor": (0, False), "timeout_s": (0, False), "hertz_frames": (2, True),
                              "hertz_elems_per_radius": (1, True), "hertz_growth": (1, True),
                              "hertz_min_increment_ratio": (0, False)}

    out: str = "results/calculix"
    """output folder: check.json, check.md, runs/<label>/ (ccx decks and results)"""
    preset: Literal["tiny", "cpu", "paper"] = "tiny"
    """panel mesh preset"""
    designs: str = DESIGNS
    """panel designs [µm], 'T1,T2;T1,T2;...' ('' for none)"""
    labels: str = LABELS
    """a label per design"""
    penalty_factor: float = 0.1
    """contact penalty factor in both codes (k_p = factor x E'/h)"""
    increments_per_frame: int = 2
    """ccx's largest increment = output_dt / this"""
    frames: int = 0
    """panel frames of 4 µs (0: the scene's 100, a 400 µs window); fewer for a smoke run"""
    hertz: bool = False
    """also run the Hertz case (--hertz; ~30 s with --hertz_elems_per_radius 4 --hertz_growth 1.3
    --hertz_frames 120 --increments_per_frame 1 --hertz_min_increment_ratio 0.005; ~12 s per implicit increment
    on the default 5,974-node mesh, docs/results/calculix.md)"""
    hertz_penalty_factor: float = 1.0
    """contact penalty factor of the Hertz case in both codes (sim/hertz.py's own check uses 2)"""
    timeout_s: float = 1200.0
    """per ccx run"""
    hertz_frames: int = 120
    """frames over the Hertz window (gap / v + 1.4 t_c)"""
    hertz_elems_per_radius: float = 10.0
    """Hertz mesh: elements across the contact radius (sim/hertz.py hertz_mesh_spec)"""
    hertz_growth: float = 1.15
    """Hertz mesh: growth ratio of the element sizes outside the fine zone (coarser far field: larger)"""
    slave_faces: bool = True
    """the contact's slave surface as the ball's faces, so ccx's springs act at the nominal k_p
    (--no_slave_faces: its nodes, ~10x stiffer, how the first tables were made; docs/results/calculix.md)"""
    hertz_min_increment_ratio: float = 0.05
    """Hertz: ccx's smallest increment / its largest (the contact's stiff springs need ~0.1 of a 0.6 µs frame)"""


def main(argv=None) -> int:
    args = cli.parse(CheckArgs, argv, description=__doc__, prog="python -m experiments.calculix_check")
    from pathlib import Path

    import matplotlib
    matplotlib.use("Agg")   # files only; set here, in the entry point

    from pcmgn_jax.data.calculix import CalculixNotFoundError, CalculixRunError, find_ccx
    from pcmgn_jax.eval.calculix_runs import hertz_case, panel_case, plot_forces, write_report

    try:
        find_ccx()
    except CalculixNotFoundError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    out = Path(args.out)
    command = cli.command_line("experiments.calculix_check", argv)
    cases, failed = [], []
    designs = [d for d in args.designs.split(";") if d.strip()]
    labels = args.labels.split(",")
    todo = [(labels[k] if k < len(labels) else f"design_{k}", d) for k, d in enumerate(designs)]
    if args.hertz:
        todo.append(("hertz", None))
    for label, d in todo:   # the panel first, Hertz last; a failing case is reported and the others go on
        try:
            cases.append(hertz_case(out, args) if d is None else
                         panel_case(out, args, [float(v) * 1e-6 for v in d.split(",")], label))
        except CalculixRunError as err:
            print(f"error: {label}: {err}", file=sys.stderr)
            failed.append(label)
        write_report(out, cases, args, command)   # after every case: a long run keeps what it has
    print("\n".join(write_report(out, cases, args, command)))
    plot_forces(out / "check.json", out / "check.png")
    return 2 if failed else 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
