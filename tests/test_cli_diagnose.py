"""``online-backlash diagnose``: the JSON contract, plot and report files, errors, and a measured recording."""

from __future__ import annotations

import csv
import json

import pytest
from davinci_runs import DAVINCI, UNITS, WITH_TORQUE

from online_backlash.cli import main
from online_backlash.simulation import synthetic
from online_backlash.simulation.rig import simulate_rig

KEYS = {
    "rms_before_deg",
    "rms_after_deg",
    "noise_floor_deg",
    "backlash_before_deg",
    "backlash_after_deg",
    "effects",
    "unexplained",
}
EFFECT_KEYS = {"name", "parameters", "rms_before_deg", "rms_after_deg", "evidence"}
RUN49 = DAVINCI / "tool4_L_run49_0.5Hz_torque100pct.csv"


@pytest.fixture(scope="module")
def te_log(tmp_path_factory):
    rec = simulate_rig(duration_s=30.0, seed=7)
    t, m, y, _ = synthetic.transmission_error(rec)
    path = tmp_path_factory.mktemp("logs") / "te.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time", "motor", "load"])
        for row in zip(t, m, y):
            w.writerow([f"{row[0]:.6f}", f"{row[1]:.9f}", f"{row[2]:.9f}"])
    return path


def test_json_contract_plot_and_report(te_log, tmp_path, capsys):
    png, md = tmp_path / "r.png", tmp_path / "r.md"
    code = main(["diagnose", str(te_log), "--ratio", "30", "--json", "--plot", str(png), "--report", str(md)])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert KEYS <= set(out)
    assert [e["name"] for e in out["effects"]] == ["transmission_error"]
    assert EFFECT_KEYS <= set(out["effects"][0])
    assert out["unexplained"] == []
    assert out["rms_after_deg"] < 0.5 * out["rms_before_deg"]
    assert out["backlash_after_deg"] == pytest.approx(0.5, rel=0.02)
    assert png.read_bytes()[:4] == b"\x89PNG"
    text = md.read_text()
    assert "`transmission_error`" in text and str(png) in text
    # the held-out figures, in the JSON evidence and the report, with the residual on the term's own axis
    ev = out["effects"][0]["evidence"]
    assert ev["heldout_gain"] > 0.5 and ev["heldout_gain_in_final_model"] > 0.5
    assert ev["heldout_split"]["split"] == "reversal cycles"
    assert "- held out: " in text and "residual against its own axis, load angle (deg)" in text


def test_text_output(te_log, capsys):
    assert main(["diagnose", str(te_log), "--ratio", "30", "--max-terms", "0"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("# Residual diagnosis") and "no effect was added" in out


def test_floor_ratio_stops_the_loop_sooner(te_log, capsys):
    """--floor-ratio R: no term once the residual is within R times the floor; below 1 is an error line."""
    assert main(["diagnose", str(te_log), "--ratio", "30", "--json", "--floor-ratio", "1e6"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["effects"] == [] and out["rms_after_deg"] == out["rms_before_deg"]
    assert main(["diagnose", str(te_log), "--ratio", "30", "--floor-ratio", "0.5"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "floor_ratio" in err and "Traceback" not in err


def test_errors_are_one_line(tmp_path, capsys):
    assert main(["diagnose", str(tmp_path / "missing.csv"), "--ratio", "30"]) == 1
    assert capsys.readouterr().err.startswith("error: ")
    bad = tmp_path / "bad.csv"
    bad.write_text("time,motor,load\n0,1,2\n0.001,x,3\n")
    assert main(["diagnose", str(bad), "--ratio", "30"]) == 1
    assert "bad.csv:3" in capsys.readouterr().err


def test_measured_recording(capsys):
    assert RUN49.exists(), f"measured data missing: {RUN49}"
    assert main(["diagnose", str(RUN49), *UNITS, "--columns", WITH_TORQUE, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["backlash_before_deg"] == pytest.approx(1.74, abs=0.05)
    assert 0.15 < out["rms_before_deg"] < 0.25
    assert out["rms_after_deg"] < 0.5 * out["rms_before_deg"]
    assert out["noise_floor_deg"] == pytest.approx(360 / 8192 / 12**0.5, rel=0.2)
    for e in out["effects"] + out["unexplained"]:
        assert e["rms_after_deg"] < e["rms_before_deg"]
        assert e["evidence"]["heldout_gain"] >= 0.05  # every term holds on cycles it was not fitted on
