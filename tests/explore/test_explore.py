"""The explorer (pcmgn_jax.explore, experiments/explore.py): its state logic without a browser, and the page
driven in headless Chromium (Debian's chromium + chromedriver, through selenium).

The run: a regression-only tiny run (config.json over six tiny-preset solver trajectories of a 12-frame
window, no checkpoint), made once per module (~15 s, most of it the solver's compilation). The MGN path
(a tiny model trained on the same data) is the slow test at the end.
"""
from __future__ import annotations

import json
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from fixtures.helpers import tiny_solver_dataset

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"


@pytest.fixture(scope="module")
def regression_run(tmp_path_factory):
    """(run directory, its Explorer): a tiny run without a checkpoint or metrics, six training designs."""
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.explore import Explorer

    root = tmp_path_factory.mktemp("explore")
    data, run = tiny_solver_dataset(root, n_train=6, n_frames=12), root / "run"
    run.mkdir()
    TrainConfig.from_preset("tiny", dataset_dir=str(data), n_train=6, n_val=0, n_test=0).save_json(run / "config.json")
    # every baseline but the POD ROM (its fit and field transfer cost seconds here; the slow test has it)
    return run, Explorer(run, kinds=("none", "nearest", "poly2", "rbf", "kriging", "mop"), log=lambda s: None)


# ---- the state logic (no browser) -------------------------------------------------------------------

def test_parameters_units_and_slider_range():
    from pcmgn_jax.explore.types import parameter
    p = parameter("OCA1", 50e-6, 150e-6)
    assert (p.unit, p.scale, p.label) == ("µm", 1e6, "OCA1 thickness")
    assert np.allclose(p.slider_range(), (25e-6, 175e-6))
    assert not p.outside(50e-6) and not p.outside(150e-6 * (1 + 1e-12)) and p.outside(49e-6) and p.outside(151e-6)
    assert parameter("ball.radius", 4e-3, 6e-3).unit == "mm" and parameter("ball.velocity", 0.5, 0.75).unit == "m/s"


def test_a_directory_without_a_run_is_a_clear_error(tmp_path):
    from pcmgn_jax.explore import Explorer, RunError
    with pytest.raises(RunError, match="no config.json, not a training run directory"):
        Explorer(tmp_path)
    pytest.importorskip("dash")
    from experiments import explore
    from pcmgn_jax import cli
    assert cli.run(explore.main, ["--workdir", str(tmp_path)]) == 2     # "error: ..." on stderr, no traceback


def test_a_run_without_oled_or_data_is_a_clear_error(tmp_path, tiny_trajs):
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.data.trajectory_io import write_trajectory
    from pcmgn_jax.explore import Explorer, RunError
    TrainConfig.from_preset("tiny", dataset_dir=str(tmp_path / "nowhere")).save_json(tmp_path / "config.json")
    with pytest.raises(RunError, match="cannot read its training data"):
        Explorer(tmp_path)
    (tmp_path / "data" / "train").mkdir(parents=True)
    for i, t in enumerate(tiny_trajs):          # synthetic CG + PLATE panels: no OLED layer
        write_trajectory(t, tmp_path / "data" / "train" / f"t{i}")
    TrainConfig.from_preset("tiny", dataset_dir=str(tmp_path / "data"), n_train=3, n_val=0,
                            n_test=0).save_json(tmp_path / "config.json")
    with pytest.raises(RunError, match="no part named 'OLED'"):
        Explorer(tmp_path)


def test_regression_only_run_states_and_flags(regression_run):
    _, ex = regression_run
    assert ex.names == ("OCA1", "OCA2") and ex.default == "kriging" and "mgn" not in ex.models
    assert [(p.low, p.high) for p in ex.params] == [(50e-6, 150e-6)] * 2      # the dataset's LHS box
    notes = " ".join(ex.notes)
    assert "no checkpoint" in notes and "eval/metrics.json is missing" in notes
    inside = ex.view(ex.start)
    assert inside.flags == [] and inside.headline.startswith("OLED objective (area mean) by kriging: ")
    assert "± " in inside.headline and "GP posterior std" in inside.headline
    rows = {r["name"]: r for r in inside.rows}
    assert rows["mgn"]["text"].startswith("n/a: no checkpoint")
    assert rows["kriging"]["std"] > 0 and all(rows[k]["mpa"] > 0 for k in ("nearest", "poly2", "rbf", "mop"))
    assert rows["none"]["mpa"] == 0
    moved = ex.view(ex.start + np.array([30e-6, 0.0]))
    assert moved.headline != inside.headline and moved.flags == []
    assert moved.figures["field"]["data"] != inside.figures["field"]["data"]
    out = ex.view(np.array([30e-6, 100e-6]))
    assert any(f.startswith("OUT OF THE TRAINING BOX: OCA1 thickness = 30 µm outside 50–150 µm") for f in out.flags)
    assert "OUTSIDE" in out.figures["box"]["layout"]["title"]["text"]
    assert ex.out_of_box(np.array([30e-6, 100e-6])) == [True, False]
    json.dumps(out.figures)                                        # plain JSON for the page
    # log colours: the field's colour bar spans the decades from the cover glass down past the OLED's MPa
    bar = inside.figures["field"]["data"][-1]["marker"]
    assert bar["cmax"] - bar["cmin"] == 5 and "MPa (log)" in bar["colorbar"]["title"]["text"]


def test_objective_history_averages_to_the_objective(regression_run):
    from pcmgn_jax import metrics
    _, ex = regression_run
    t = ex.train[0]
    per_frame = ex.objective_history(t, t.von_mises)
    assert per_frame.shape == (t.n_frames,)
    assert np.isclose(per_frame.mean(), float(metrics.oled_objective_of(t, part=ex.part)))


def test_solver_check_overlays_truth_and_error(regression_run):
    from pcmgn_jax.surrogates.inputs import design_of
    _, ex = regression_run
    x = design_of(ex.train[1])               # a training design: the solver is compiled for its step already
    truth = ex.check(x)
    assert abs(truth.objective_mpa - ex.rows(x)[-1]["mpa"]) < 1e-12 and truth.force.max() > 1     # [N]
    v = ex.view(x, show="error:poly2")
    assert v.show == "error:poly2" and "truth" in ex.choices(x)
    assert {r["name"] for r in v.rows} >= {"truth", "poly2"}
    poly = next(r for r in v.rows if r["name"] == "poly2")
    assert poly["error_pct"] < 1.0           # poly2 passes through its training designs (nearly)
    names = [t["name"] for t in v.figures["history"]["data"] if "name" in t]
    assert "contact force (solver)" in names and any(n.startswith("solver") for n in names)


# ---- the page in a browser --------------------------------------------------------------------------

def _browser():
    pytest.importorskip("dash", reason="the explorer's page needs dash (pip install -e '.[explore]')")
    pytest.importorskip("selenium", reason="the browser test needs selenium (pip install -e '.[dev]')")
    for path, what in ((CHROMIUM, "chromium"), (CHROMEDRIVER, "chromedriver")):
        if not Path(path).exists() and shutil.which(what) is None:
            pytest.skip(f"no {what} ({path}): apt-get install -y chromium chromium-driver")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM if Path(CHROMIUM).exists() else shutil.which("chromium")
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1500,2600"):
        opts.add_argument(a)
    driver = Path(CHROMEDRIVER) if Path(CHROMEDRIVER).exists() else shutil.which("chromedriver")
    return webdriver.Chrome(service=Service(str(driver)), options=opts)


class _Server:
    """The explorer's Dash app on a free local port, in a thread of this process."""

    def __init__(self, explorer):
        from werkzeug.serving import make_server

        from pcmgn_jax.explore.app import build_app
        self.http = make_server("127.0.0.1", 0, build_app(explorer).server, threaded=True)
        self.url = f"http://127.0.0.1:{self.http.server_port}/"
        self.thread = threading.Thread(target=self.http.serve_forever, daemon=True)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.http.shutdown()
        self.thread.join(10)


def _figure(driver, gid: str) -> str:
    """The figure the page shows in graph ``gid`` (its plotly data, as JSON)."""
    return driver.execute_script(
        f"const g = document.querySelector('#{gid} .js-plotly-plot'); "
        f"return g && g.data ? JSON.stringify(g.data.map(t => [t.x, t.y, t.fillcolor])) : '';")


def _wait(driver, fn, timeout=30.0):
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout:
        got = fn()
        if got:
            return got
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s")


def _drive(explorer, tmp_path, name: str, *, check: bool = False):
    """Open the page, move OCA1's slider, check the objective and the field change, flag an out-of-box
    value, optionally run the solver check; save a screenshot. Returns the slider-move response time [s]."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    driver = _browser()
    try:
        with _Server(explorer) as server:
            driver.get(server.url)
            def text(eid):          # "" until the page has rendered the element
                found = driver.find_elements(By.ID, eid)
                return found[0].text if found else ""

            def objective():
                return text("objective")
            before = _wait(driver, lambda: objective() if "MPa" in objective() else "")
            field0 = _wait(driver, lambda: _figure(driver, "field"))
            thumb = driver.find_element(By.CSS_SELECTOR, "#p-0 [role=slider]")
            thumb.click()                          # focus, then three page steps up (+30 µm)
            t0 = time.perf_counter()
            for _ in range(3):
                thumb.send_keys(Keys.PAGE_UP)
            after = _wait(driver, lambda: objective() if objective() != before and "MPa" in objective() else "")
            seconds = time.perf_counter() - t0
            _wait(driver, lambda: _figure(driver, "field") != field0)
            assert driver.find_element(By.CSS_SELECTOR, "#p-0 input").get_attribute("value") == "130"
            print(f"\nslider move: objective '{before}' -> '{after}' in {seconds:.2f} s (browser round trip)")
            thumb.send_keys(Keys.END)              # the slider's end, beyond the training box
            _wait(driver, lambda: "OUT OF THE TRAINING BOX" in text("flags"))
            if check:
                driver.find_element(By.ID, "check").click()
                _wait(driver, lambda: "solver at" in text("solver-status"), 120)
                _wait(driver, lambda: "the solver (truth)" in text("table"))
            shot = tmp_path / f"{name}.png"
            driver.save_screenshot(str(shot))
            print(f"screenshot: {shot}")
            assert "Traceback" not in driver.page_source
    finally:
        driver.quit()
    return seconds


def test_page_in_headless_chromium(regression_run, tmp_path):
    """Move a slider in the browser: the objective text and the field figure change; out-of-box is flagged."""
    _, ex = regression_run
    assert _drive(ex, tmp_path, "explorer_regression") < 10


@pytest.mark.slow   # trains a tiny MGN (~1 min) and runs the solver check from the page
def test_page_with_mgn_and_solver_check(regression_run, tmp_path):
    from pcmgn_jax.config import TrainConfig
    from pcmgn_jax.explore import Explorer
    from pcmgn_jax.train import loop as training

    run, reg = regression_run
    cfg = TrainConfig.load(run / "config.json").replace(n_train=5, n_val=1, num_steps=40, ckpt_every=40,
                                                        val_every=40, progress=False)
    mgn_run = tmp_path / "mgn_run"
    training.train(cfg, mgn_run, train_trajs=reg.train[:5], val_trajs=reg.train[5:])
    ex = Explorer(mgn_run, log=lambda s: None, mgn_spread=True)
    assert ex.default == "mgn" and ex.mgn_seconds is not None
    ex.predict_rest(ex.start)
    rows = {r["name"]: r for r in ex.view(ex.start).rows}
    assert rows["mgn"]["mpa"] is not None and rows["rom"]["mpa"] is not None
    assert rows["mgn"]["std"] is not None and rows["mgn"]["std"] >= 0 and "training residuals" in ex.headline(ex.start)
    assert _drive(ex, tmp_path, "explorer_mgn", check=True) < 10
