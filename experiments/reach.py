"""Reach report: how many mesh hops separate the contact from every part, and how much of the OLED each
processor sees in one network pass (issue 39; the rule: pcmgn_jax/mgn/reach.py, docs/design.md §5.3).

python -m experiments.reach --preset cpu                 # the preset's mesh of the default scene
python -m experiments.reach --workdir RUN                # a run's mesh preset and processor (config.json)

Writes OUT.json (default results/reach/reach_PRESET.json, or RUN/reach.json) and prints the tables.
The variants: local message passing with the preset's steps, 15 and 30 steps, the multi-scale and the
attention processor with the preset's steps (and, with --workdir, the run's own processor).
"""
from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from pcmgn_jax import cli
from pcmgn_jax.presets import PresetName


@dataclass(frozen=True)
class ReachArgs:
    # cli.check_bounds: {flag: (lowest value, inclusive[, highest])}
    BOUNDS: ClassVar[dict] = {"levels": (0, True)}
    preset: PresetName = "cpu"   # training preset (its mesh preset and message-passing steps); ignored with --workdir
    workdir: str = ""        # a run directory: its config.json's mesh preset, steps and processor
    levels: int = 0          # coarse levels of the multi-scale variant (0: the formulation's reach_levels)
    out: str = ""            # output JSON ("" -> results/reach/reach_PRESET.json, or RUN/reach.json)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = cli.parse(ReachArgs, argv, description=__doc__, prog="python -m experiments.reach")
    from pcmgn_jax.atomic import atomic_write_text
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.mgn.contact import contact_parts
    from pcmgn_jax.mgn.reach import reach_report, report_table
    from pcmgn_jax.scene import default_scene
    from pcmgn_jax.sim.mesh import MESH_PRESETS, build_mesh, roi

    if args.workdir:
        cfg = TrainConfig.load(Path(args.workdir) / "config.json")
    else:
        cfg = TrainConfig.from_preset(args.preset)
    form = cfg.formulation
    mesh_preset = cfg.data_preset if cfg.data_preset in MESH_PRESETS else "cpu"
    scene = default_scene()
    mesh, _ = roi(build_mesh(scene, mesh_preset), mesh_preset)
    steps, levels = cfg.message_passing_steps, args.levels or form.reach_levels
    variants = {f"local {steps}": dict(steps=steps, reach="local")}
    for k in (15, 30):
        variants.setdefault(f"local {k}", dict(steps=k, reach="local"))
    variants[f"multiscale {steps} (L={levels})"] = dict(steps=steps, reach="multiscale", levels=levels)
    variants[f"attention {steps}"] = dict(steps=steps, reach="attention")
    if args.workdir:
        variants["this run"] = dict(steps=steps, reach=form.reach, levels=form.reach_levels)
    report = reach_report(mesh, mesh.part_names, contact_parts(scene)[1], variants)
    report.update(preset=cfg.preset, mesh_preset=mesh_preset, command=cli.command_line("experiments.reach", argv))
    out = Path(args.out or (Path(args.workdir) / "reach.json" if args.workdir
                            else f"results/reach/reach_{cfg.preset}.json"))
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, json.dumps(report, indent=2) + "\n")
    print(f"reach report, preset {cfg.preset} (mesh {mesh_preset}): {out}")
    print("\n".join(report_table(report)))
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
