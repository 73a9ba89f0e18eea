"""``online-backlash serve``: the read-only fleet page, checked in a real headless chromium."""

from __future__ import annotations

import hashlib
import io
import json
import os
import select
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from fleet_store import fill_gearbox
from PIL import Image
from sqlalchemy.exc import DBAPIError

from online_backlash.history.alarms import STATES
from online_backlash.history.store import HistoryStore
from online_backlash.web import fleet_rows, open_read_only

NOW = time.time()
CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--window-size=1280,2400",
    "--force-device-scale-factor=1",
)


def _fill_fleet(db) -> None:
    with HistoryStore(db, create=True) as store:
        fill_gearbox(store, "GB-1", np.linspace(10.0, 12.0, 12), NOW - 60.0, with_parameters=True)  # ok, growing
        fill_gearbox(store, "GB-2", np.linspace(15.0, 19.2, 12), NOW - 60.0, with_parameters=False)  # warning


@pytest.fixture
def fleet_db(tmp_path):
    db = tmp_path / "fleet.db"
    _fill_fleet(db)
    return db


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def server(fleet_db):
    """``online-backlash serve`` on a free localhost port, as a process; yields its base URL."""
    before = _digest(fleet_db)
    code = "import sys; from online_backlash.cli import main; sys.exit(main())"
    log = fleet_db.parent / "serve.log"  # the request log (a file: a full pipe would stall the server)
    with open(log, "w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-c", code, "serve", "--db", str(fleet_db), "--port", "0", "--refresh", "60"],
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
        )
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 60.0)
        line = proc.stdout.readline() if ready else ""
        assert " on http://127.0.0.1:" in line, f"serve did not start: {line!r} {log.read_text()}"
        yield line.split(" on ", 1)[1].split()[0]
    finally:
        proc.terminate()
        assert proc.wait(timeout=20) == 0, log.read_text()
        proc.stdout.close()
    assert _digest(fleet_db) == before, "serving changed the store"


@pytest.fixture
def browser(tmp_path):
    """Debian's chromium, headless, through selenium and chromedriver. Missing: a failure, not a skip."""
    if not (CHROMIUM.exists() and CHROMEDRIVER.exists()):
        pytest.fail(
            "chromium and chromedriver are needed: apt-get install chromium chromium-driver (scripts/test does)"
        )
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for flag in (*CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'chromium-profile'}"):
        options.add_argument(flag)
    driver = webdriver.Chrome(options=options, service=Service(executable_path=str(CHROMEDRIVER)))
    try:
        yield driver
    finally:
        driver.quit()


def _region(screenshot: Image.Image, element) -> np.ndarray:
    """The screenshot's pixels under ``element`` (CSS pixels, device scale 1), grey levels 0..255."""
    r = element.rect
    box = (int(r["x"]), int(r["y"]), int(r["x"] + r["width"]), int(r["y"] + r["height"]))
    return np.asarray(screenshot.convert("L").crop(box), dtype=float)


def test_the_page_shows_the_fleet_in_a_real_browser(server, browser, fleet_db, tmp_path):
    from selenium.webdriver.common.by import By

    browser.get(server)
    rows = browser.find_elements(By.CSS_SELECTOR, "#fleet tbody tr")
    cells = [[td.text for td in row.find_elements(By.TAG_NAME, "td")] for row in rows]
    assert [c[0] for c in cells] == ["GB-1", "GB-2"]
    assert [c[1] for c in cells] == ["ok", "warning"]
    assert cells[0][2].startswith("12.00 ± 0.24") and cells[1][2].startswith("19.20 ± 0.24")
    # the trend and the forecast in the words history uses (issue 28): one formatting for every reader
    with open_read_only(fleet_db) as store:
        expected = fleet_rows(store, 168.0)
    assert [(c[3], c[4]) for c in cells] == [(r.trend, r.forecast) for r in expected]
    assert all(c[3].startswith("+") and " arcmin per 1,000 " in c[3] and ", around 20" in c[4] for c in cells), cells
    assert all(c[5][:2] == "20" for c in cells), cells  # last-seen dates
    refresh = browser.find_element(By.CSS_SELECTOR, "meta[http-equiv=refresh]").get_attribute("content")
    assert refresh == "60"

    images = browser.find_elements(By.CSS_SELECTOR, "img.wear")
    loops = browser.find_elements(By.CSS_SELECTOR, "img.loop")
    assert len(images) == 2 and len(loops) == 1  # GB-2 stores no eq. (1) parameters
    assert "GB-2" in browser.find_element(By.CSS_SELECTOR, "p.no-loop").text
    for img in [*images, *loops]:
        assert browser.execute_script("return arguments[0].complete && arguments[0].naturalWidth", img) > 100

    png = browser.get_screenshot_as_png()
    (tmp_path / "fleet.png").write_bytes(png)
    shot = Image.open(io.BytesIO(png))
    table = _region(shot, browser.find_element(By.ID, "fleet"))
    plot = _region(shot, images[0])
    assert table.shape[0] > 40 and plot.shape[1] > 300
    for pixels in (table, plot):
        assert (pixels < 128).mean() > 0.01 and pixels.std() > 20  # ink on a light background, not blank
    # the state colours are painted: the ok cell is greenish, the warning cell yellowish
    rgb = np.asarray(shot.convert("RGB"), dtype=int)
    ok_cell, warn_cell = (rows[i].find_element(By.CLASS_NAME, "state").rect for i in (0, 1))
    ok_px = rgb[int(ok_cell["y"]) + 2, int(ok_cell["x"]) + 2]
    warn_px = rgb[int(warn_cell["y"]) + 2, int(warn_cell["x"]) + 2]
    assert ok_px[1] > ok_px[0] + 20 and warn_px[0] > warn_px[2] + 50


def _get(url: str, method: str = "GET") -> tuple[int, str, bytes]:
    try:
        with urllib.request.urlopen(urllib.request.Request(url, method=method), timeout=30) as r:
            return r.status, r.headers.get("Content-Type", ""), r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, "", b""


def test_plots_are_png_and_nothing_writes(server):
    status, kind, body = _get(f"{server}gearbox/GB-1/wear.png")
    assert (status, kind, body[:8]) == (200, "image/png", b"\x89PNG\r\n\x1a\n")
    assert _get(f"{server}gearbox/GB-1/characteristic.png")[0] == 200
    assert _get(f"{server}gearbox/GB-2/characteristic.png")[0] == 404  # no eq. (1) parameters stored
    assert _get(f"{server}gearbox/GB-9/wear.png")[0] == 404
    for method in ("POST", "PUT", "DELETE"):
        assert _get(server, method)[0] == 405


def test_the_store_is_opened_read_only(store_db):
    _fill_fleet(store_db)
    with open_read_only(store_db) as store:
        assert store.gearbox_ids() == ["GB-1", "GB-2"]
        with pytest.raises(
            DBAPIError, match=r"readonly database|read-only transaction"
        ):  # refused by the database itself
            store.set_alarm_levels("GB-3", 30.0, limit_arcmin=21.0)
    with HistoryStore(store_db) as store:
        assert store.gearbox_ids() == ["GB-1", "GB-2"] and store.gearbox("GB-1").revision == 2


def test_a_missing_store_is_refused(tmp_path, capsys):
    from online_backlash.cli import main

    assert main(["serve", "--db", str(tmp_path / "none.db"), "--port", "0"]) == 1
    assert "no history store" in capsys.readouterr().err
    assert not (tmp_path / "none.db").exists() and os.listdir(tmp_path) == []


def _history_json(db, gearbox_id: str) -> dict:
    """``history --json`` of one gearbox, as a subprocess (the command a user would compare a scrape with)."""
    code = "import sys; from online_backlash.cli import main; sys.exit(main())"
    done = subprocess.run(
        [sys.executable, "-c", code, "history", "--db", str(db), "--gearbox", gearbox_id, "--json"],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    return json.loads(done.stdout)


def test_metrics_are_the_history_figures_to_the_last_digit(server, fleet_db):
    from prometheus_client.parser import text_string_to_metric_families

    before = time.time()
    status, kind, body = _get(f"{server}metrics")
    after = time.time()
    assert status == 200 and kind.startswith("text/plain; version=")
    samples: dict[tuple[str, tuple], float] = {}
    for family in text_string_to_metric_families(body.decode()):
        assert family.type == "gauge", family
        for s in family.samples:
            samples[(s.name, tuple(sorted(s.labels.items())))] = s.value
    for gearbox_id in ("GB-1", "GB-2"):
        history = _history_json(fleet_db, gearbox_id)
        label = (("gearbox", gearbox_id),)

        def value(name: str, labels: tuple = label) -> float:
            return samples[(f"online_backlash_{name}", labels)]

        last = history["estimates"][-1]
        assert value("play_arcmin") == history["play_arcmin"]  # exactly: the same float, printed in full
        assert value("play_std_arcmin") == last["backlash_std_arcmin"]
        assert value("hours_to_limit") == history["forecast_hours_to_limit"]
        assert value("warn_arcmin") == history["warn_arcmin"] and value("limit_arcmin") == history["limit_arcmin"]
        assert value("play_observable") == 1.0
        age = value("last_estimate_age_seconds")
        assert before - age <= last["time_unix_s"] + 1e-6 and last["time_unix_s"] <= after - age + 1e-6
        states = {s: value("state", (("gearbox", gearbox_id), ("state", s))) for s in STATES}
        assert states == {s: float(s == history["state"]) for s in states}, states
    assert {k[1][0][1] for k in samples if k[0] == "online_backlash_play_arcmin"} == {"GB-1", "GB-2"}


def test_metrics_leave_out_what_is_not_known(store_db):
    """A gearbox with levels but no estimate yet: its state is unknown and no play sample is made up (SQLite and
    PostgreSQL, each opened read-only)."""
    from prometheus_client.parser import text_string_to_metric_families

    from online_backlash.web import create_app

    db = store_db
    with HistoryStore(db, create=True) as store:
        store.set_alarm_levels("GB-new", 30.0, warn_arcmin=18.0, limit_arcmin=21.0)
    with open_read_only(db) as store:
        response = create_app(store).test_client().get("/metrics")
    assert response.status_code == 200
    families = text_string_to_metric_families(response.text)
    samples = {(s.name, tuple(sorted(s.labels.items()))): s.value for f in families for s in f.samples}
    names = {name for name, _ in samples}
    unknown = {"online_backlash_play_arcmin", "online_backlash_play_std_arcmin", "online_backlash_hours_to_limit"}
    assert not names & unknown
    assert samples[("online_backlash_state", (("gearbox", "GB-new"), ("state", "unknown")))] == 1.0
    assert samples[("online_backlash_limit_arcmin", (("gearbox", "GB-new"),))] == 21.0
