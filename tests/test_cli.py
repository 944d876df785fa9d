"""The entry points' command lines (pcmgn_jax.cli, tyro): flag spellings, presets, errors, --resume."""
import pytest

from fixtures.helpers import ROOT
from pcmgn_jax import cli
from pcmgn_jax.config import TrainConfig
from pcmgn_jax.mgn.formulation import FORMULATIONS
from pcmgn_jax.presets import PRESETS


def test_paper_style_flags():
    args = cli.parse_train(["--lambda_pen=10", "--noise_std=3e-7", "--seed=1", "--latent_size=32",
                            "--message_passing_steps=4", "--num_steps=2000", "--noise_parts=none"])
    cfg = args.config
    assert cfg.lambda_pen == 10.0 and cfg.seed == 1 and cfg.latent_size == 32
    assert cfg.message_passing_steps == 4 and cfg.num_steps == 2000 and cfg.noise_parts == "none"
    assert cfg.noise_std == 3e-7            # the old parser turned '-' in values into '_'
    assert args.run_dir.as_posix() == "runs/cpu" and args.resume is False


def test_space_separated_hyphens_and_booleans():
    cfg = cli.parse_train(["--preset", "tiny", "--lambda-pen", "0", "--no-progress"]).config
    assert cfg.lambda_pen == 0 and cfg.progress is False
    assert cli.parse_config(["--progress=false"]).progress is False
    assert cli.parse_config(["--no_progress", "--progress"]).progress is True
    args = cli.parse_train(["--workdir", "runs/x", "--resume"])
    assert args.run_dir.as_posix() == "runs/x" and args.resume


def test_contact_projection_and_ema_flags():
    cfg = cli.parse_config(["--contact_projection=off", "--ema_decay=0.99"])
    assert cfg.ema_decay == 0.99 and cfg.formulation.contact_projection is False
    assert cli.parse_config(["--no_contact_projection"]).formulation.contact_projection is False
    assert TrainConfig.from_preset("cpu").formulation.contact_projection is True  # the default formulation's
    assert TrainConfig.from_preset("cpu", formulation="paper").formulation.contact_projection is False
    assert TrainConfig.from_preset("cpu", formulation="paper", contact_projection=True).formulation.contact_projection
    with pytest.raises(ValueError, match="cannot read 'yes!' as a boolean"):
        cli.parse_config(["--contact_projection=yes!"])
    with pytest.raises(ValueError, match=r"ema_decay=1.0 must be in \[0, 1\)"):
        TrainConfig.from_preset("cpu", ema_decay=1.0)


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_preset_fills_defaults(preset):
    cfg = cli.parse_train(["--preset", preset]).config
    assert cfg == TrainConfig.from_preset(preset)
    # a flag overrides the preset, whatever the order
    assert cli.parse_train(["--latent_size=24", f"--preset={preset}"]).config == \
        TrainConfig.from_preset(preset, latent_size=24)
    assert cli.parse_train([]).config == TrainConfig.from_preset("cpu")


def test_unknown_flag_and_preset_errors():
    with pytest.raises(ValueError, match=r"unknown flag.*--lamda_pen \(did you mean --lambda_pen\?\)"):
        cli.parse_train(["--lamda_pen=10"])
    with pytest.raises(ValueError, match="unknown preset 'huge'"):
        cli.parse_train(["--preset", "huge"])
    with pytest.raises(ValueError, match="unknown flag"):
        cli.parse_config(["--lamda_pen=10"])
    with pytest.raises(ValueError, match="boolean"):
        cli.parse_config(["--progress=maybe"])
    with pytest.raises(ValueError, match="Error parsing --latent_size: invalid literal"):   # tyro's message, one line
        cli.parse_train(["--latent_size=big"])
    with pytest.raises(ValueError, match=r"^invalid choice 'bogus' for argument '--origin'"):
        cli.parse_train(["--origin=bogus"])


def test_help_lists_every_field_with_its_comment(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "250")
    with pytest.raises(SystemExit) as exit_:
        cli.parse_train(["--help"], prog="train")
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    import re

    from pcmgn_jax.config import FIELDS, GROUPS
    assert not set(GROUPS) & set(re.findall(r"--([\w.]+)", out)) and "--data.n_train" not in out
    assert len(FIELDS) > 40
    for name in FIELDS:
        assert f"--{name}" in out, name
    assert "weight of the penetration term" in out and "--workdir" in out and "--resume" in out


def test_resume_refuses_changed_config(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    saved = TrainConfig.from_preset("tiny", lambda_pen=10.0)
    saved.save_json(run / "config.json")
    # the saved config supplies the defaults: --resume alone continues the run
    args = cli.parse_train(["--workdir", str(run), "--resume"])
    assert args.config == saved and args.resume
    assert cli.parse_train(["--workdir", str(run), "--resume", "--lambda_pen=10"]).config == saved
    with pytest.raises(ValueError, match=r"--resume: the config differs .*\['lambda_pen', 'latent_size'\]"):
        cli.parse_train(["--workdir", str(run), "--resume", "--lambda_pen=0", "--latent_size=8"])
    with pytest.raises(ValueError, match=r"\['preset'"):
        cli.parse_train(["--workdir", str(run), "--resume", "--preset", "cpu"])
    # without --resume the preset defaults apply (the training loop starts a fresh run)
    assert cli.parse_train(["--workdir", str(run)]).config == TrainConfig.from_preset("cpu")


def test_config_diff_names_fields():
    a = TrainConfig.from_preset("tiny")
    assert cli.config_diff(a, a) == {}
    assert cli.config_diff(a, a.replace(seed=3, lambda_pen=1.0)) == {"lambda_pen": (a.lambda_pen, 1.0),
                                                                    "seed": (0, 3)}


def test_entry_point_flags(tmp_path, capsys):
    from experiments import generate, hertz_check, panel_report

    args = cli.parse(hertz_check.HertzArgs, ["--radius-mm", "5", "--velocity", "0.62631", "--target", "glass",
                                             "--json", "out.json"])
    assert args.radius_mm == 5 and args.target == "glass" and args.json == "out.json"
    from pcmgn_jax.sim.hertz import ELEMS_PER_RADIUS
    assert args.elems_per_radius == ELEMS_PER_RADIUS
    args = cli.parse(generate.GenerateArgs, ["--preset", "cpu", "--n_train", "14", "--n_test", "6",
                                             "--out", "data/cpu"])
    assert (args.n_train, args.n_test, args.out) == (14, 6, "data/cpu")
    args = cli.parse(generate.GenerateArgs, ["--designs", "40,40;40,160", "--split", "extrap", "--out", "d"])
    assert args.designs == "40,40;40,160" and args.split == "extrap" and args.n_train is None
    assert generate.preset_sizes("cpu") == (TrainConfig().n_train, TrainConfig().n_val, TrainConfig().n_test)
    assert cli.parse(panel_report.PanelReportArgs, ["--preset", "cpu", "--frames", "130"]).frames == 130
    assert generate.main(["--out", str(tmp_path), "--bogus", "1"]) == 2
    assert "unknown flag(s): --bogus" in capsys.readouterr().err


def test_formulation_selector_and_nested_flags():
    cfg = cli.parse_config(["--preset", "tiny", "--panel_target=velocity", "--formulation=dynamic", "--no_rigid_ball",
                            "--scene_features=ball_radius,layer_thickness"])
    assert cfg.formulation_name == "dynamic"  # the selector applies first, wherever it stands
    assert cfg.formulation == FORMULATIONS["dynamic"].replace(
        rigid_ball=False, scene_features=("ball_radius", "layer_thickness"))
    assert cli.parse_config(["--preset", "family", "--scene_features=none"]).formulation.scene_features == ()
    assert cli.parse_config(["--preset", "family"]).formulation.scene_features == ("ball_radius", "layer_thickness")
    with pytest.raises(ValueError, match="unknown flag.*--target"):
        cli.parse_config(["--target=velocity"])
    with pytest.raises(ValueError, match="formulation='nope'"):
        cli.parse_config(["--formulation=nope"])


def test_config_json_nests_the_formulation_and_reads_old_flat_files(tmp_path):
    cfg = TrainConfig.from_preset("family_tiny", formulation="paper", panel_target="position")
    d = cfg.to_dict()
    assert d["formulation"]["panel_target"] == "position" and d["formulation_name"] == "paper"
    cfg.save_json(tmp_path / "config.json")
    assert TrainConfig.load(tmp_path / "config.json") == cfg
    import dataclasses
    grouped = dataclasses.asdict(cfg)   # the groups' form
    assert set(grouped) == {"data", "model", "loss", "optim", "log"} and cfg.model.latent_size == cfg.latent_size
    assert TrainConfig.from_json(grouped) == cfg
    flat = {k: v for k, v in d.items() if k not in ("formulation", "formulation_name")}
    flat.update(formulation="paper", target="velocity", panel_target="position", ball_target="", ball_model="rigid",
                normalization="", features="", loss_weighting="", panel_model="", contact_projection="on",
                scene_features="ball_radius")
    old = TrainConfig.from_json(flat)
    assert old.formulation_name == "paper" and old.formulation == FORMULATIONS["paper"].replace(
        panel_target="position", rigid_ball=True, contact_projection=True, scene_features=("ball_radius",))
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['bogus'\]"):
        TrainConfig.from_json({**d, "bogus": 1})
    with pytest.raises(ValueError, match=r"config loss: unknown key\(s\) \['latent_size'\]"):
        TrainConfig.from_json({**grouped, "loss": {**grouped["loss"], "latent_size": 8}})


def test_resume_names_nested_fields(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    TrainConfig.from_preset("tiny").save_json(run / "config.json")
    with pytest.raises(ValueError, match=r"formulation\.panel_target: saved 'total_displacement', given 'velocity'"):
        cli.parse_train(["--preset", "tiny", "--workdir", str(run), "--resume", "--panel_target=velocity",
                         "--panel_model=dynamic"])


def test_console_help_lists_every_subcommand(capsys):
    """``pcmgn --help``: every entry point in experiments/ with its docstring's first sentence."""
    import ast
    from pathlib import Path

    from experiments import console
    root = Path(console.__file__).parent
    mains = {p.stem for p in root.glob("*.py")
             if any(isinstance(n, ast.FunctionDef) and n.name == "main" for n in ast.parse(p.read_text()).body)}
    assert mains - {"console"} <= set(console.COMMANDS), "an entry point missing from console.COMMANDS"
    assert {"train", "evaluate", "generate", "optimize", "explore", "report"} <= set(console.COMMANDS)
    assert console.main(["--help"]) == 0
    out = capsys.readouterr().out
    for name in console.COMMANDS:
        assert f"\n  {name} " in out, name
    assert "Evaluate a run on its test split" in out and "Train the MeshGraphNet" in out
    assert "``" not in out and "python -m experiments.train [" not in out


def test_console_runs_the_entry_points_main(tmp_path, capsys, monkeypatch):
    from experiments import console
    with pytest.raises(SystemExit) as exit_:
        console.main(["optimize-table", "--help"])                # hyphen or underscore: the module's own --help
    assert exit_.value.code == 0 and "--files" in capsys.readouterr().out
    assert console.main(["report", "--workdir", str(tmp_path)]) == 2   # experiments.report.main's ValueError
    assert "eval/metrics.json" in capsys.readouterr().err
    assert console.main(["trian"]) == 2
    assert "unknown command 'trian' (did you mean 'train'?)" in capsys.readouterr().err
    assert console.main([]) == 2 and "no command given" in capsys.readouterr().err
    monkeypatch.setattr(console, "COMMANDS", console.COMMANDS + ("not_built",))
    assert console.main(["not_built"]) == 2
    assert "experiments/not_built.py is not in this checkout" in capsys.readouterr().err
    console.main(["--help"])
    assert "not_built" in capsys.readouterr().out


def test_console_groups_name_their_commands(capsys):
    """``pcmgn calculix check`` is ``pcmgn calculix_check``; ``pcmgn calculix --flags`` still runs calculix."""
    from experiments import console
    assert console.resolve(["calculix", "check", "--x"]) == ("calculix_check", ["--x"])
    assert console.resolve(["calculix", "run", "--x"]) == ("calculix", ["--x"])
    assert console.resolve(["calculix", "--preset", "tiny"]) == ("calculix", ["--preset", "tiny"])
    assert console.resolve(["optimize", "table"]) == ("optimize_table", [])
    assert console.resolve(["optimize-table"]) == ("optimize_table", [])
    for subs in console.GROUPS.values():
        assert set(subs.values()) <= set(console.COMMANDS)
    with pytest.raises(SystemExit) as exit_:
        console.main(["optimize", "table", "--help"])
    assert exit_.value.code == 0 and "--files" in capsys.readouterr().out
    console.main(["--help"])
    assert "pcmgn calculix check" in capsys.readouterr().out


def test_console_script_entry_point(tmp_path):
    """pyproject names the console script; once installed, it works from any directory."""
    import shutil
    import subprocess
    import tomllib

    root = ROOT
    project = tomllib.loads((root / "pyproject.toml").read_text())
    assert project["project"]["scripts"]["pcmgn"] == "experiments.console:main"
    assert "experiments*" in project["tool"]["setuptools"]["packages"]["find"]["include"]
    exe = shutil.which("pcmgn")
    if exe is None:
        pytest.skip("the pcmgn script is not installed (pip install -e .)")
    run = subprocess.run([exe, "--help"], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and "report" in run.stdout, run.stderr
    run = subprocess.run([exe, "nope"], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "unknown command 'nope'" in run.stderr


def _documented_train_flags() -> dict[str, str]:
    """{flag name: page} of every ``--flag`` after ``experiments.train`` on a line of the README, docs/ or a
    results page (the command up to a comment, a pipe or a backtick)."""
    import re
    flags: dict[str, str] = {}
    pages = [ROOT / "README.md", *(ROOT / "docs").rglob("*.md"), *(ROOT / "results").rglob("*.md")]
    for page in pages:
        for cmd in re.findall(r"experiments\.train([^`|#&\n]*)", page.read_text()):
            for flag in re.findall(r"--([A-Za-z][\w-]*)", cmd):
                flags.setdefault(flag.replace("-", "_"), str(page.relative_to(ROOT)))
    return flags


def test_every_documented_train_flag_parses():
    """Every experiments.train flag the docs and results pages show is a flag of the command line (the
    config's nesting by concern leaves them flat), and the main job's command parses to TrainConfig()."""
    flags = _documented_train_flags()
    assert {"n_train", "dataset_dir", "num_steps", "seed", "preset", "formulation", "reach"} <= set(flags)
    names, bools = cli._flags(cli.TrainArgs)
    known = names | {"no_" + b for b in bools} | {"formulation"}
    assert not {f: p for f, p in flags.items() if f not in known}
    args = cli.parse_train(["--dataset_dir", "data/cpu", "--n_train", "100", "--num_steps", "50", "--seed", "3"])
    assert args.config == TrainConfig().replace(dataset_dir="data/cpu", n_train=100, num_steps=50, seed=3)
    assert cli.parse_train([]).config == TrainConfig() == TrainConfig.from_preset("cpu")
    assert cli.parse_train(["--lambda_pen=10", "--noise_std", "3e-7"]).config == TrainConfig.of(lambda_pen=10.0,
                                                                                                noise_std=3e-7)


def test_old_config_files_without_the_main_jobs_fields_keep_their_old_defaults():
    """A config.json written before a field existed ran with that field's old default: the fields whose
    default became the main job's read their old values when missing (config_files.BEFORE_MAIN_JOB_DEFAULTS)."""
    from pcmgn_jax.config_files import BEFORE_MAIN_JOB_DEFAULTS
    full = TrainConfig().to_dict()
    old = {k: v for k, v in full.items() if k not in BEFORE_MAIN_JOB_DEFAULTS}
    cfg = TrainConfig.from_json(old)
    assert {k: getattr(cfg, k) for k in BEFORE_MAIN_JOB_DEFAULTS} == BEFORE_MAIN_JOB_DEFAULTS
    assert TrainConfig.from_json(full) == TrainConfig()


def test_the_library_names_values_and_the_command_line_maps_them_to_flags(tmp_path):
    """train.pipeline.claim refuses a folder naming the folder and the values (RunFolderError, no flag);
    experiments.train says the same in its flags; config.check_resume names fields, parse_train adds the flags."""
    from experiments import train
    from pcmgn_jax.train.pipeline import RunFolderError, claim
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text("{}")
    cases = [(dict(resume=True, overwrite=True), "resume_and_overwrite", "resume=True and overwrite=True",
              "--resume and --overwrite"),
             (dict(resume=False, overwrite=False), "holds_run", "continue it (resume=True)", "--resume, or start over")]
    for kw, reason, says, flags in cases:
        with pytest.raises(RunFolderError) as err:
            claim(run, **kw)
        assert err.value.reason == reason and says in str(err.value) and "--" not in str(err.value)
        assert flags in train.flag_message(err.value)
    with pytest.raises(RunFolderError, match="exists and is not a folder") as err:
        claim(run / "config.json", resume=False, overwrite=False)
    assert train.flag_message(err.value).startswith("--workdir ")
    TrainConfig.from_preset("tiny").save_json(run / "config.json")
    from pcmgn_jax.config import check_resume
    with pytest.raises(ValueError, match=r"differs .*\['latent_size'\]") as err:
        check_resume(TrainConfig.from_preset("tiny", latent_size=8), run)
    assert "--" not in str(err.value)


def test_generate_and_study_say_their_flags_where_the_library_names_values(tmp_path, capsys):
    """--shard with --merge, an unknown --name / --formulations: the command names its flags before the library
    (which names the values: shard=..., merge=True; study name=...)."""
    from experiments import generate, study
    from pcmgn_jax.data.dataset import DatasetError, ensure_dataset
    assert cli.run(generate.main, ["--out", str(tmp_path / "d"), "--shard", "0/2", "--merge"]) == 2
    assert "--shard and --merge exclude each other" in capsys.readouterr().err and not (tmp_path / "d").exists()
    with pytest.raises(DatasetError, match=r"shard=\(0, 2\) and merge=True exclude each other") as err:
        ensure_dataset(tmp_path / "d", preset="tiny", shard=(0, 2), merge=True)
    assert "--" not in str(err.value)
    from pcmgn_jax.studies import paper
    with pytest.raises(ValueError, match="--formulations: unknown"):
        study.main(["--name", "lambda", "--formulations", "paper,nope"])
    with pytest.raises(ValueError, match="study name='nope' must be one of"):
        paper.run("nope", formulations=["paper"], seeds=[0], num_steps=1, runs=str(tmp_path), out=str(tmp_path),
                  data="", command="")


def test_a_setting_the_library_refuses_is_said_as_its_flag_on_the_command_line(capsys):
    """The library names the setting (``name: why``); ``cli.run`` says it as the flag (``--name: why``)."""
    from pcmgn_jax import cli
    from pcmgn_jax.data.importers.parts import parse_parts
    from pcmgn_jax.errors import SettingError
    with pytest.raises(SettingError, match=r"^parts: 'ball' is not NAME=GROUP$"):
        parse_parts("ball")
    assert cli.run(lambda argv: parse_parts("ball"), []) == 2
    assert "error: --parts: 'ball' is not NAME=GROUP" in capsys.readouterr().err



def test_no_library_error_spells_a_flag():
    """Library errors name settings, values and files, never a ``--flag`` (pcmgn_jax/errors.py); cli.py, the
    command line's own module, is the one place that does."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "pcmgn_jax"
    pattern = re.compile(r"raise \w+\(\s*f?[\"']--[a-z]")
    found = [f"{p.relative_to(root.parent)}:{text.count(chr(10), 0, m.start()) + 1}"
             for p in sorted(root.rglob("*.py")) if p.name != "cli.py"
             for text in [p.read_text()] for m in pattern.finditer(text)]
    assert not found, f"library errors that spell a flag: {found}"


def test_stress_target_is_a_flag_and_an_older_config_json_without_it_is_linear():
    """--stress_target=log reaches the formulation; a config.json written before the field (its formulation without
    the key) loads with the linear target, which it was trained with."""
    cfg = cli.parse_train(["--preset", "tiny", "--stress_target=log"]).config
    assert cfg.formulation.stress_target == "log" and cfg.formulation.replace(stress_target="linear") == \
        TrainConfig.from_preset("tiny").formulation
    assert TrainConfig.from_json(cfg.to_dict()) == cfg
    old = TrainConfig.from_preset("tiny").to_dict()
    del old["formulation"]["stress_target"]
    assert TrainConfig.from_json(old).formulation.stress_target == "linear"
    assert TrainConfig.from_json(old) == TrainConfig.from_preset("tiny")
    with pytest.raises((ValueError, SystemExit)):
        cli.parse_train(["--preset", "tiny", "--stress_target=sqrt"])
