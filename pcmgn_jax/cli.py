"""Command lines of the entry points in ``experiments/``: tyro on frozen dataclasses, one flag per field.

Every entry point declares a frozen dataclass whose fields (one line each, with a comment that becomes the
``--help`` text) are its flags, and calls :func:`parse`:

    args = cli.parse(GenerateArgs, argv, description=__doc__)

Flags are written ``--key=value`` or ``--key value`` with underscores (the paper's style,
``--lambda_pen=10``); hyphens in a flag name are accepted too (``--radius-mm``), never changed in values
(``--noise_std=3e-7``). Booleans: ``--flag`` / ``--no_flag`` / ``--flag=true|false``. An unknown flag
raises ``ValueError`` naming it (entry points print it and exit with status 2).

Training: :func:`parse_train` reads ``--preset NAME`` first (one of ``pcmgn_jax.presets.PRESETS``: tiny, cpu,
paper, family, family_tiny, stack, stack_tiny), fills every default from that preset's training settings, then
parses every :class:`TrainConfig` field as a flag, plus ``--workdir``, ``--resume`` and ``--overwrite``.
``--formulation=paper|default|dynamic|realtime`` is read first too, wherever it stands: it sets the nested
formulation to ``FORMULATIONS[name]`` (with the preset's formulation overrides) before the formulation's field flags
(``--panel_target=X``, ``--rigid_ball``, ``--contact_projection``, ``--scene_features=a,b|none``) apply. With
``--resume`` the defaults come from the run's ``config.json`` instead, and a flag
that changes a saved value is refused (:func:`pcmgn_jax.config.check_resume`).
"""
from __future__ import annotations

import contextlib
import dataclasses
import difflib
import io
import math
import shlex
import sys
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Sequence, TypeVar

import tyro

from pcmgn_jax.config import (
    FORMULATION_FIELDS,
    TrainConfig,
    check_resume,
    config_diff,
    resolve_formulation,
    scene_feature_names,
)
from pcmgn_jax.presets import PRESETS

__all__ = ["TrainArgs", "check_resume", "config_diff", "given_flags", "normalize_argv", "parse", "parse_config",
           "parse_train", "preset_of", "refuse_inapplicable", "train_rules"]

T = TypeVar("T")
_TRUE, _FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


def _flags(cls) -> tuple[set[str], set[str]]:
    """(flag names, boolean flag names) of dataclass ``cls``; nested dataclass fields are flattened
    (their prefix is omitted, see :class:`TrainArgs`)."""
    names: set[str] = set()
    bools: set[str] = set()
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        typ = hints[f.name]
        if dataclasses.is_dataclass(typ):
            n, b = _flags(typ)
            names |= n
            bools |= b
        else:
            names.add(f.name)
            if typ is bool:
                bools.add(f.name)
    return names, bools


def normalize_argv(cls, argv: Sequence[str]) -> list[str]:
    """``argv`` with flag names in underscore form and ``--flag=true|false`` as ``--flag`` / ``--no_flag``.

    Values are never changed. Raises ``ValueError`` naming unknown flags (with the closest known ones).
    """
    names, bools = _flags(cls)
    known = names | {"no_" + b for b in bools} | {"help"}
    out, unknown = [], []
    for arg in argv:
        if not arg.startswith("--") or arg == "--":
            out.append(arg)
            continue
        key, eq, value = arg[2:].partition("=")
        key = key.replace("-", "_")
        if key not in known:
            unknown.append(key)
            continue
        if eq and key in bools:
            if value.lower() not in _TRUE + _FALSE:
                raise ValueError(f"flag --{key}: cannot read {value!r} as a boolean (true | false)")
            out.append(f"--{key}" if value.lower() in _TRUE else f"--no_{key}")
        else:
            out.append(f"--{key}{eq}{value}")
    if unknown:
        hints = []
        for key in unknown:
            close = difflib.get_close_matches(key, sorted(known), n=1)
            hints.append(f"--{key}" + (f" (did you mean --{close[0]}?)" if close else ""))
        raise ValueError(f"unknown flag(s): {', '.join(hints)}; run with --help for the list")
    return out


def parse(cls: type[T], argv: Sequence[str] | None = None, *, description: str | None = None,
          default: T | None = None, prog: str | None = None) -> T:
    """Parse ``argv`` (default ``sys.argv[1:]``) into frozen dataclass ``cls`` (tyro, underscore flags).

    ``--help`` prints every field with its comment and exits. Raises ``ValueError`` for an unknown flag,
    a value of the wrong type or one the dataclass rejects (tyro's framed message as one line), and for a
    number out of range (:func:`check_bounds`).
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    kw: dict[str, Any] = {} if default is None else {"default": default}
    said = io.StringIO()
    try:
        with contextlib.redirect_stderr(said):
            args = tyro.cli(cls, args=normalize_argv(cls, argv), description=description, prog=prog,
                            use_underscores=True, config=(tyro.conf.OmitArgPrefixes,), **kw)
    except SystemExit as err:
        if err.code in (0, None):
            raise
        raise ValueError(_one_line(said.getvalue())) from None
    check_bounds(args)
    return args


def _one_line(box: str) -> str:
    """tyro's framed error message as one line (the box's text, without its frame and the help pointer)."""
    text = []
    for line in box.splitlines():
        line = line.strip().strip("│").strip()
        if line.startswith("For full helptext"):
            break
        if line and not set(line) <= set("─╭╮╰╯ ") and not line.startswith(("╭", "╰")):
            text.append(line)
    return " ".join(text) or box.strip() or "cannot parse the command line (run with --help)"


def check_bounds(args) -> None:
    """ValueError naming the first flag out of range: a float flag that is not finite, a required text flag
    (a path) that is empty, or one below its entry in the class's ``BOUNDS`` ({field: (low, inclusive[,
    high])}; None values skipped) or above its high: out-of-range numbers are refused before anything runs,
    never a traceback from deep inside."""
    bounds = getattr(type(args), "BOUNDS", {})
    for f in dataclasses.fields(args):
        value = getattr(args, f.name)
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"--{f.name}={value}: must be a finite number")
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        if required and isinstance(value, str) and not value.strip():
            raise ValueError(f"--{f.name} is empty: give a path (an empty one would be the current folder)")
        if f.name in bounds and value is not None:
            low, inclusive, *high = bounds[f.name]
            if value < low or (value == low and not inclusive):
                raise ValueError(f"--{f.name}={value}: must be {'>=' if inclusive else '>'} {low}")
            if high and value > high[0]:
                raise ValueError(f"--{f.name}={value}: must be <= {high[0]}")


def command_line(module: str, argv: Sequence[str] | None = None) -> str:
    """The command as a user would type it again, for the record: ``python -m MODULE ARG...`` with every
    argument shell-quoted (``argv`` default ``sys.argv[1:]``)."""
    args = sys.argv[1:] if argv is None else list(argv)
    return " ".join(["python", "-m", module, *(shlex.quote(str(a)) for a in args)])


def keyed_paths(specs: Sequence[str], flag: str) -> dict[str, list[Path]]:
    """``["K=a.json,b.json", ...]`` (a flag's ``KEY=FILE[,FILE...]`` values) -> {KEY: [Path of each file]},
    in order. ValueError naming the flag and the spec for a malformed spec, a repeated key or a missing file."""
    out: dict[str, list[Path]] = {}
    for spec in specs:
        key, sep, files = spec.partition("=")
        if not sep or not key or not files:
            raise ValueError(f"--{flag} {spec!r}: expected KEY=FILE.json[,FILE.json...]")
        if key in out:
            raise ValueError(f"--{flag}: {key!r} is given twice")
        paths = [Path(f) for f in files.split(",")]
        for p in paths:
            if not p.is_file():
                raise ValueError(f"--{flag} {key}: {p} does not exist")
        out[key] = paths
    return out


METRICS_KEYS = ("position_mae_um", "stress_mae_mpa")   # what every evaluation's metrics.json holds


def keyed_json_files(specs: Sequence[str], flag: str, require: Sequence[str] = METRICS_KEYS) -> dict[str, list[dict]]:
    """:func:`keyed_paths`, each file parsed as JSON: ValueError naming the file if it is not JSON or lacks a key
    of ``require`` (default: an evaluation's metrics.json), never a table of nothing."""
    import json

    def load(p: Path):
        try:
            d = json.loads(p.read_text())
        except json.JSONDecodeError as err:
            raise ValueError(f"--{flag}: {p} is not JSON ({err})") from None
        missing = [k for k in require if not isinstance(d, dict) or k not in d]
        if missing:
            raise ValueError(f"--{flag}: {p} is not a metrics.json of experiments.evaluate (no {missing})")
        return d
    return {key: [load(p) for p in paths] for key, paths in keyed_paths(specs, flag).items()}


def run(main_fn, argv: Sequence[str] | None = None) -> int:
    """Call ``main_fn(argv)``, turning a ``ValueError`` into ``error: ...`` on stderr and status 2, and an
    ``OSError`` of a path (a folder where a file goes, a file where a folder goes, no permission, ...) into
    ``error: PATH: what`` (status 2), never a traceback."""
    from pcmgn_jax.errors import SettingError
    try:
        return main_fn(argv)
    except SettingError as err:                 # a setting the library refused, said as its flag
        print(f"error: {err.as_flag()}", file=sys.stderr)
        return 2
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        if err.filename is None:
            raise
        print(f"error: {err.filename}: {err.strerror or err} (check the paths given)", file=sys.stderr)
        return 2


def _value_of(argv: Sequence[str], flag: str, default: str | None) -> str | None:
    """The last value of ``--FLAG`` in ``argv`` (``--FLAG X`` or ``--FLAG=X``), else ``default``."""
    argv = list(argv)
    found = default
    for i, arg in enumerate(argv):
        if arg.startswith(f"--{flag}="):
            found = arg.split("=", 1)[1]
        elif arg == f"--{flag}" and i + 1 < len(argv):
            found = argv[i + 1]
    return found


def given_flags(argv: Sequence[str]) -> set[str]:
    """Names (underscore form, without ``no_``) of the flags written in ``argv``."""
    out = set()
    for arg in argv:
        if arg.startswith("--") and arg != "--":
            key = arg[2:].partition("=")[0].replace("-", "_")
            out.add(key[3:] if key.startswith("no_") else key)
    return out


def refuse_inapplicable(given: set[str], rules: dict[str, str | None]) -> None:
    """ValueError naming each flag written (``given``, :func:`given_flags`) whose rule says why it does not apply
    to the chosen preset or mode (``rules``: flag -> the reason, or None where it applies): a flag is refused,
    never silently ignored."""
    bad = [f"--{flag} does not apply: {why}" for flag, why in rules.items() if why and flag in given]
    if bad:
        raise ValueError("; ".join(bad))


def train_rules(args: "TrainArgs") -> dict[str, str | None]:
    """The training flags that apply only to some settings (:func:`refuse_inapplicable`). The noise levels and
    ``lambda_start`` stay allowed beside ``noise_parts=none`` / ``lambda_pen=0``: the studies' recorded
    commands write them for every cell (pcmgn_jax.studies.cells.as_flags)."""
    cfg, form = args.config, args.config.formulation
    return {"reach_levels": None if form.reach == "multiscale" else f"--reach={form.reach} (only multiscale: levels)",
            **{k: None if form.reach == "attention" else f"--reach={form.reach} (only attention has slices and heads)"
               for k in ("reach_slices", "reach_heads")},
            "residual_ball": None if cfg.residual_of else "no --residual_of (the network moves the ball itself)",
            **{k: None if args.coordinator_address else "no --coordinator_address (one host)"
               for k in ("num_processes", "process_id")}}


def preset_of(argv: Sequence[str], default: str = "cpu") -> str:
    """The value of ``--preset`` in ``argv`` (``--preset X`` or ``--preset=X``), else ``default``."""
    found = _value_of(argv, "preset", default)
    if found not in PRESETS:
        raise ValueError(f"--preset: unknown preset {found!r}; choose one of {sorted(PRESETS)}")
    return found


@dataclass(frozen=True)
class TrainArgs:
    """``python -m experiments.train``: every TrainConfig field, then the run directory."""

    config: Annotated[TrainConfig, tyro.conf.arg(name="")]   # the flags are its fields, no prefix
    workdir: str = ""        # run directory (checkpoints, metrics.jsonl, config.json); "" -> runs/<preset>
    resume: bool = False     # continue the run in --workdir from its last checkpoint (same config only)
    overwrite: bool = False  # start over in a --workdir that holds a run: the earlier run moves to WORKDIR.old-<time>
    # several hosts (README "Several machines"): jax.distributed.initialize before training; not saved
    coordinator_address: str = ""  # host:port of process 0, reachable from every host; "" -> one host
    num_processes: int = 1   # processes in the run (one per host)
    process_id: int = 0      # this process's index, 0 .. num_processes - 1

    @property
    def run_dir(self) -> Path:
        return Path(self.workdir or f"runs/{self.config.preset}")

    def initialize_distributed(self) -> None:
        """``jax.distributed.initialize`` when ``coordinator_address`` is set; call before any jax computation."""
        if not self.coordinator_address:
            return
        if not 0 <= self.process_id < self.num_processes:
            raise ValueError(f"--process_id={self.process_id} must be in 0 .. num_processes - 1 "
                             f"(--num_processes={self.num_processes})")
        import jax
        jax.distributed.initialize(coordinator_address=self.coordinator_address,
                                   num_processes=self.num_processes, process_id=self.process_id)


def _train_argv(argv: Sequence[str]) -> tuple[list[str], str | None]:
    """(``argv`` without the ``--formulation`` selector, the selected name or None), with
    ``--scene_features=a,b`` (or ``none``) rewritten as tyro's ``--scene_features a b``."""
    name = _value_of(argv, "formulation", None)
    out: list[str] = []
    it = iter(argv)
    for arg in it:
        key = "--" + arg.partition("=")[0][2:].replace("-", "_") if arg.startswith("--") else arg
        if key == "--formulation":
            if "=" not in arg:
                next(it, None)
            continue
        if key == "--scene_features":
            value = arg.partition("=")[2] if "=" in arg else next(it, "")
            out += ["--scene_features", *scene_feature_names(value)]
            continue
        out.append(arg)
    return out, name


def _select(cfg: TrainConfig, name: str | None) -> TrainConfig:
    """``cfg`` with the formulation ``FORMULATIONS[name]`` and its preset's formulation fields (the
    ``--formulation`` selector), or as it is."""
    if name is None:
        return cfg
    return cfg.replace(**resolve_formulation(
        {k: v for k, v in PRESETS[cfg.preset].train.items() if k in FORMULATION_FIELDS}, {"formulation": name},
        check=False))


def parse_train(argv: Sequence[str] | None = None, *, description: str | None = None,
                prog: str | None = None) -> TrainArgs:
    """Training flags: preset defaults (or, with ``--resume``, the saved config), then each flag.

    With ``--resume`` and an existing ``WORKDIR/config.json``, a flag that changes a saved value raises
    ``ValueError`` naming the fields.
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    preset = preset_of(argv)
    argv, name = _train_argv(argv)
    probe = parse(TrainArgs, argv, description=description, prog=prog,
                  default=TrainArgs(config=_select(TrainConfig.from_preset(preset), name)))
    saved = probe.run_dir / "config.json"
    if not (probe.resume and saved.exists()):
        refuse_inapplicable(given_flags(argv), train_rules(probe))
        return probe
    base = _select(TrainConfig.load(saved), name)
    args = parse(TrainArgs, argv, description=description, prog=prog, default=TrainArgs(config=base))
    try:
        check_resume(args.config, args.run_dir)
    except ValueError as err:   # the library names the fields; say it in flags
        raise ValueError(f"--resume: {err}; drop those flags to continue the run, or train in a new --workdir") \
            from None
    refuse_inapplicable(given_flags(argv), train_rules(args))
    return args


def parse_config(argv: Sequence[str]) -> TrainConfig:
    """A :class:`TrainConfig` from ``--key=value`` flags (``--preset`` fills the defaults).

    Library form: raises ``ValueError`` for an unknown flag or a bad value (tyro's message, one line).
    """
    argv = list(argv)
    preset = preset_of(argv)
    rest, name = _train_argv(argv)
    return parse(TrainConfig, rest, default=_select(TrainConfig.from_preset(preset), name),
                 prog="pcmgn_jax.cli.parse_config")
