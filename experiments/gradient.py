"""The OLED objective's exact gradient from the solver, per named scene parameter, as JSON.

  python -m experiments.gradient --preset cpu --design 120,80 --out g.json                 # every default parameter
  python -m experiments.gradient --preset tiny --design 50,100 --fd_steps 1e-3,1e-4 --out g.json   # + a step study
  python -m experiments.gradient --scene my.toml --params OCA1.thickness,CG.youngs,ball.radius --out g.json
  python -m experiments.gradient --table 'results/gradients/*.json' --out results/gradients/table.md
  python -m experiments.gradient --dataset_dir DATA --split train --n 25 --out grads.json   # a dataset's designs

With ``--dataset_dir``: the objective and its gradient with respect to the row's parameters at the first ``--n``
designs of a generated dataset's split, one file a gradient-enhanced surrogate reads (resumable: rerun the
same command after a kill; pcmgn_jax/data/gradients.py). A stack dataset's rows too: each design in its own
scene, a log10 modulus by the chain rule, a presence flag and an absent layer's numbers 0.

Writes JSON (pcmgn_jax/sim/gradient_check.py): the objective [Pa], its gradient per named parameter in SI units
(every layer's thickness and Young's modulus, the ball's radius and speed by default; ``--params`` names others:
``<layer|ball>.<thickness|youngs|poisson|density>``, ``ball.radius``, ``ball.velocity``), the wall time of the
value and of value and gradient (float64, after compilation), the peak memory, and with ``--fd_steps`` central
finite differences of the same run at each relative step. The derivative is at the batch's fixed time step
(docs/results/gradients.md).
"""
from __future__ import annotations

import json
import sys
from dataclasses import dataclass

from pcmgn_jax import cli


@dataclass(frozen=True)
class GradientArgs:
    preset: str = "cpu"                 # mesh preset (tiny, cpu, paper)
    design: str = ""                    # design-layer thicknesses in µm, comma-separated (default: the scene's)
    scene: str = ""                     # a scene file (TOML / JSON; default: the paper's panel)
    params: str = ""                    # names, comma-separated (default: thicknesses, moduli; ball radius, speed)
    reading: str = "area_mean"          # objective reading: area_mean | node_mean | disc_mean | peak
    fd_steps: str = ""                  # relative central-difference steps, comma-separated (1e-4,1e-5); empty: none
    fd_params: str = ""                 # parameters of the step study (default: all of --params)
    out: str = ""                       # write the JSON here
    table: str = ""                     # instead: the accuracy and cost tables (markdown) of these JSON files (a glob)
    dataset_dir: str = ""               # instead: the gradients at a generated dataset's designs (--split, --n, --out)
    split: str = "train"                # the dataset's split
    n: int = 0                          # its first n designs (0: all)


def main(argv=None) -> int:
    args = cli.parse(GradientArgs, argv, description=__doc__, prog="python -m experiments.gradient")
    from pcmgn_jax.atomic import atomic_write_json
    from pcmgn_jax.scene import Scene
    from pcmgn_jax.sim.gradient_check import gradient_report

    if args.dataset_dir:
        from pcmgn_jax.data.gradients import design_gradients
        from pcmgn_jax.errors import SettingError
        if not args.out:
            raise SettingError("out", "the gradients of --dataset_dir go to a file: give one")
        design_gradients(args.dataset_dir, args.split, n=args.n or None, out=args.out, reading=args.reading)
        return 0
    if args.table:
        import glob

        from pcmgn_jax.sim.gradient_check import accuracy_table
        files = sorted(glob.glob(args.table))
        text = "\n".join(accuracy_table([json.loads(open(f).read()) for f in files])) + "\n"
        if args.out:
            from pcmgn_jax.atomic import atomic_write_text
            atomic_write_text(args.out, text)
        print(text)
        return 0
    scene = Scene.load(args.scene) if args.scene else Scene()
    if args.design:
        scene = scene.with_design(*(float(v) * 1e-6 for v in args.design.split(",")))

    def split(text):
        return [s.strip() for s in text.split(",") if s.strip()] or None

    report = gradient_report(scene, args.preset, names=split(args.params), reading=args.reading,
                             fd_steps=[float(s) for s in split(args.fd_steps) or []], fd_params=split(args.fd_params))
    report = {"command": "python -m experiments.gradient " + " ".join(sys.argv[1:] if argv is None else argv),
              "preset": args.preset, "design_um": [t * 1e6 for t in scene.design],
              "design_layers": list(scene.design_layers), **report}
    if args.out:
        atomic_write_json(args.out, report)
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
