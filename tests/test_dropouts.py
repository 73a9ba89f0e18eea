"""Issue 11 item 8: streams as they arrive, with dropouts and timestamp bursts.

* a short gap is bridged (the estimator keeps its state), a long gap or a jump restarts it;
* bursts of bunched host timestamps with a continuous frame counter are not gaps;
* a warm start that cannot complete says that gaps are why.

Each failure is first reproduced (bridging off: ``GapPolicy(bridge_s=0)`` / ``--bridge-s 0``),
then shown fixed.
"""

from __future__ import annotations

import dataclasses
import json

import can
import numpy as np
import pytest
from rig_can import RIG_CAN

from online_backlash.cli import main
from online_backlash.cli._output import EXIT_NO_PLAY
from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.codecs.gaps import GapDetector
from online_backlash.errors import InvalidParameterError
from online_backlash.estimators import BacklashRLS
from online_backlash.gap_policy import BRIDGE_S, JUMP_DEG, GapPolicy
from online_backlash.log_fit import fit_batch, fit_recursive
from online_backlash.pipeline import Pipeline
from online_backlash.replay import CsvLog, read_csv_arrays
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.rig_logs import rig_can_frames, write_rig_serial_capture

PLAY_DEG = 0.5


@pytest.fixture(scope="module")
def dropout_csv(tmp_path_factory):
    """60 s at 1 kHz, 0.5 deg of play, 4 rows lost every 5 s (rows 1000-1003 of every 5000)."""
    path = tmp_path_factory.mktemp("dropouts") / "dropouts.csv"
    simulate_rig(duration_s=60.0, ratio=30.0, play_deg=PLAY_DEG, seed=0).write_csv(path)
    header, *rows = path.read_text().splitlines()
    path.write_text("\n".join([header, *(r for i, r in enumerate(rows) if not 1000 <= i % 5000 < 1004)]) + "\n")
    return path


def _recursive(path, **kwargs):
    with CsvLog(path) as log:
        report, est = fit_recursive(log.iter_chunks(), 30.0, **kwargs)
    return report, est


def test_without_bridging_a_4_row_dropout_every_5_s_spoils_the_warm_start(dropout_csv):
    report, est = _recursive(dropout_csv, gap_policy=GapPolicy(bridge_s=0.0))
    assert est.warm_start_["method"] == "cold"  # the failure of issue 11 item 8: 0.4506 deg
    # (with the full-engagement rule of issue 27 the lines' play, read where their information lies, is 0.229
    # +- 0.136 deg after the cold start: withheld as not resolved, NaN)
    assert not abs(report.backlash_deg - PLAY_DEG) <= 0.02
    reason = report.extra["warm_start"]["reason"]
    assert reason.startswith("8 gaps in the data cut the 40000 buffered samples into stretches of at most 4996")
    assert report.extra["gaps_bridged"] == 0


def test_a_4_row_dropout_every_5_s_is_bridged(dropout_csv, capsys):
    rows = []
    report, est = _recursive(dropout_csv, trace=rows.append, every_s=1.0)
    batch, _ = fit_batch(read_csv_arrays(dropout_csv), 30.0)
    assert est.warm_start_["method"] == "batch" and "warm_start" not in report.extra
    assert report.backlash_deg == pytest.approx(PLAY_DEG, abs=2e-3)
    assert report.backlash_deg == pytest.approx(batch.backlash_deg, abs=2e-3)
    assert rows[0].time_s <= 12.0 and rows[0].backlash_deg == pytest.approx(
        PLAY_DEG, abs=0.01
    )  # not 41 s, not 0.026 deg
    assert report.extra["gaps_bridged"] == 12 and report.extra["gap_total_s"] == pytest.approx(12 * 0.005, abs=1e-6)
    assert main(["estimate", str(dropout_csv), "--ratio", "30", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["backlash_deg"] == pytest.approx(report.backlash_deg, abs=1e-12) and out["gaps"] == 12
    code = main(["estimate", str(dropout_csv), "--ratio", "30", "--json", "--bridge-s", "0"])
    unbridged = json.loads(capsys.readouterr().out)["backlash_deg"]
    assert code == (0 if unbridged is not None else EXIT_NO_PLAY)  # a report without a play exits 3
    assert unbridged is None or abs(unbridged - PLAY_DEG) > 0.02  # (null: not resolved, as above)


def _restarts(est: BacklashRLS) -> list[bool]:
    """The gap flags the estimator kept in its warm-up buffer (True: the reading of the motion restarts)."""
    return est.state_dict()["buffer"]["gap"]


@pytest.mark.parametrize(
    ("lost_s", "jump_deg", "restarts"),
    [(0.004, 0.0, False), (BRIDGE_S * 0.9, 0.0, False), (BRIDGE_S * 2, 0.0, True), (0.004, 2 * JUMP_DEG, True)],
)
def test_only_a_long_gap_or_a_jump_restarts_the_estimator(lost_s, jump_deg, restarts):
    rec = simulate_rig(duration_s=10.0, seed=2).to_chunk()
    cut = 4000
    lost = round(lost_s * 1000)
    keep = np.r_[0:cut, cut + lost : len(rec)]
    after_gap = np.zeros(keep.size, bool)
    after_gap[cut] = True
    load = rec.load_deg[keep] + np.where(np.arange(keep.size) >= cut, jump_deg, 0.0)
    chunk = dataclasses.replace(
        rec,
        time_s=rec.time_s[keep],
        motor_deg=rec.motor_deg[keep],
        load_deg=load,
        torque_Nm=rec.torque_Nm[keep],
        after_gap=after_gap,
        seq=None,
    )
    est = BacklashRLS(warm_start_samples=20_000)  # still buffering at the end: its buffer shows the restarts
    pipe = Pipeline(est, 30.0, every_s=None)
    for part in (chunk.slice(0, cut), chunk.slice(cut, keep.size)):  # the gap falls at a chunk boundary
        list(pipe.feed(part))
    assert _restarts(est) == [i == cut and restarts for i in range(keep.size)]
    assert (pipe.gap_tally.gaps, pipe.gap_tally.bridged) == (1, 0 if restarts else 1)
    assert pipe.gap_tally.longest_s == pytest.approx(lost_s + 0.001, abs=1e-9)


def test_a_gap_after_mark_gap_is_never_bridged():
    chunk = simulate_rig(duration_s=1.0, seed=2).to_chunk()
    chunk.after_gap[0] = True
    est = BacklashRLS()
    pipe = Pipeline(est, 30.0, every_s=None)
    list(pipe.feed(chunk.slice(0, 10)))
    pipe.mark_gap()
    list(pipe.feed(dataclasses.replace(chunk.slice(10, 20), after_gap=np.r_[True, np.zeros(9, bool)])))
    assert _restarts(est)[0] and _restarts(est)[10] and (est.gaps_.gaps, est.gaps_.bridged) == (2, 0)


@pytest.mark.parametrize("bad", [{"bridge_s": -1.0}, {"jump_deg": float("nan")}, {"bridge_s": True}])
def test_gap_policy_settings_are_checked(bad):
    with pytest.raises(InvalidParameterError):
        GapPolicy(**bad)


def _burst_times(time_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Host timestamps of a USB adapter: each sample stamped at the end of its 1-5 ms burst, frames of a burst 10 us
    apart."""
    ends = np.cumsum(rng.integers(1, 6, size=time_s.size) * 1e-3)
    burst = np.searchsorted(ends, time_s + 1e-9)
    stamped = ends[np.minimum(burst, ends.size - 1)]
    within = np.arange(time_s.size) - np.searchsorted(burst, burst)  # index of the sample in its burst
    return stamped + within * 2e-5


@pytest.fixture(scope="module")
def burst_blf(tmp_path_factory):
    """A 20 s BLF of the rig (two messages per sample, 4-bit counter continuous) with bunched timestamps."""
    rec = simulate_rig(duration_s=20.0, ratio=30.0, play_deg=PLAY_DEG, seed=6)
    times = _burst_times(rec.time_s, np.random.default_rng(0))
    frames = list(rig_can_frames(rec, DbcDecoder(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count")))
    for i, msg in enumerate(frames):
        msg.timestamp = 1.7e9 + times[i // 2] + (i % 2) * 1e-5
    path = tmp_path_factory.mktemp("bursts") / "bursts.blf"
    with can.Logger(str(path)) as writer:
        for msg in frames:
            writer.on_message_received(msg)
    return path


@pytest.mark.parametrize("period", [None, "0.001"])
def test_timestamp_bursts_with_a_continuous_counter_are_not_gaps(capsys, burst_blf, period):
    argv = ["estimate", str(burst_blf), "--ratio", "30", "--json", "--bridge-s", "0"]  # no bridging: the codec alone
    argv += RIG_CAN
    assert main(argv + ([] if period is None else ["--period", period])) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["gaps"], out["samples"], out["corrupt"], out["unpaired"]) == (0, 20000, 0, 0)
    assert out["backlash_deg"] == pytest.approx(PLAY_DEG, abs=2e-3)


def test_the_gap_rule_learns_the_period_of_bursts_from_the_counter():
    times = _burst_times(np.arange(2000) * 1e-3, np.random.default_rng(1))
    gaps = GapDetector(counter_modulus=16)
    found = [gaps.check(t, i % 16) for i, t in enumerate(times)]
    assert gaps.period_s == pytest.approx(1e-3, rel=0.3) and not any(found)
    lost = GapDetector(counter_modulus=16, period_s=1e-3)
    assert lost.check(0.0, 0) is None and lost.check(0.017, 1) is not None  # a whole counter cycle lost still shows


def test_a_serial_link_losing_a_frame_every_2_s_is_tracked(tmp_path, capsys):
    path = tmp_path / "lossy.serial"
    write_rig_serial_capture(path, "binary", duration_s=30.0, seed=7)
    frames = path.read_bytes().split(b"\0")
    path.write_bytes(b"\0".join(f for i, f in enumerate(frames) if i % 2000 != 1999))
    argv = ["track", str(path), "--ratio", "30", "--db", str(tmp_path / "h.db"), "--gearbox", "g", "--json"]
    argv += ["--serial-format", "binary", "--motor-cpr", str(2**14), "--load-cpr", str(2**17), "--every", "1"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["counters"]["gaps"] == 14 and out["counters"]["gaps_bridged"] == 14
    assert out["estimates_added"] >= 15 and out["last_estimate"]["backlash_deg"] == pytest.approx(PLAY_DEG, abs=5e-3)
