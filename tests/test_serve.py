"""``online-backlash serve``: the read-only fleet page, checked in a real headless chromium."""

from __future__ import annotations

import hashlib
import io
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
from PIL import Image
from sqlalchemy.exc import DBAPIError

from online_backlash.history.store import HistoryStore
from online_backlash.web import open_read_only

HOUR = 3600.0
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


def _fill(store, gearbox_id, play_arcmin, end_unix_s, with_parameters, warn=18.0, limit=21.0):
    """Hourly estimates of ``play_arcmin`` ending at ``end_unix_s`` in one complete run; with
    ``with_parameters`` each also stores eq. (1)'s slopes and dead-band widths (play split evenly)."""
    store.set_alarm_levels(gearbox_id, 30.0, warn_arcmin=warn, limit_arcmin=limit)
    gearbox, run = store.begin_run(gearbox_id, 30.0, "log.csv", hashlib.sha256(gearbox_id.encode()).hexdigest(), end_unix_s)
    n = len(play_arcmin)
    rows = []
    for i, p in enumerate(play_arcmin):
        half = p / 120.0 if with_parameters else None
        slope = 1.0 if with_parameters else None
        rows.append(
            dict(
                sample_index=1000 * (i + 1),
                time_unix_s=end_unix_s - (n - 1 - i) * HOUR,
                backlash_deg=p / 60.0,
                backlash_std_deg=0.004,
                c_left_deg=half,
                c_right_deg=half,
                m_left=slope,
                m_right=slope,
                residual_rms_deg=None,
                n_samples=1000 * (i + 1),
                operating_hours=float(i + 1),
                load_revolutions=100.0 * (i + 1),
                reversals=50 * (i + 1),
            )
        )
    gearbox, run = store.commit(gearbox, run, 1000 * n, {"format": 1}, rows)
    store.commit(gearbox, run, 1000 * n, {"format": 1}, counters=dict(frames=n, samples=n, corrupt=0, skipped=0, gaps=0))


def _fill_fleet(db) -> None:
    with HistoryStore(db, create=True) as store:
        _fill(store, "GB-1", np.linspace(10.0, 12.0, 12), NOW - 60.0, with_parameters=True)  # ok, growing
        _fill(store, "GB-2", np.linspace(15.0, 19.2, 12), NOW - 60.0, with_parameters=False)  # warning


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
        pytest.fail("chromium and chromedriver are needed: apt-get install chromium chromium-driver "
                    "(scripts/test does)")
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


def test_the_page_shows_the_fleet_in_a_real_browser(server, browser, tmp_path):
    from selenium.webdriver.common.by import By

    browser.get(server)
    rows = browser.find_elements(By.CSS_SELECTOR, "#fleet tbody tr")
    cells = [[td.text for td in row.find_elements(By.TAG_NAME, "td")] for row in rows]
    assert [c[0] for c in cells] == ["GB-1", "GB-2"]
    assert [c[1] for c in cells] == ["ok", "warning"]
    assert cells[0][2].startswith("12.00 ± 0.24") and cells[1][2].startswith("19.20 ± 0.24")
    assert all("arcmin/1000 h" in c[3] and c[3].startswith("+") for c in cells)
    assert all(c[4][:2] == "20" and c[5][:2] == "20" for c in cells), cells  # forecast and last-seen dates
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
        with pytest.raises(DBAPIError, match=r"readonly database|read-only transaction"):  # refused by the database itself
            store.set_alarm_levels("GB-3", 30.0, limit_arcmin=21.0)
    with HistoryStore(store_db) as store:
        assert store.gearbox_ids() == ["GB-1", "GB-2"] and store.gearbox("GB-1").revision == 2


def test_a_missing_store_is_refused(tmp_path, capsys):
    from online_backlash.cli import main

    assert main(["serve", "--db", str(tmp_path / "none.db"), "--port", "0"]) == 1
    assert "no history store" in capsys.readouterr().err
    assert not (tmp_path / "none.db").exists() and os.listdir(tmp_path) == []
