"""A log's place in calendar time (issue 28 item 5, issue 26 item 4): the measurement file's own start
time first (MDF4 header, TDMS ``wf_start_time``, Parquet timestamps, written by asammdf, npTDMS and
pyarrow with their own start-time fields), a start from the file name, a millisecond time column
found from its sample period, and copies placed by their modification times refused with the option
that places them."""

from __future__ import annotations

import datetime as dt
import json
import os
import warnings

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from measurement_cases import rig_mdf
from nptdms import ChannelObject, TdmsWriter

from online_backlash.cli import main
from online_backlash.clocks import CLOCK_MTIME, start_from_name, suggest_name_pattern, time_unit_scale
from online_backlash.errors import BacklashWarning, HistoryError, InvalidParameterError, LogFormatError
from online_backlash.history.store import HistoryStore
from online_backlash.replay import open_log
from online_backlash.simulation.rig import simulate_rig
from online_backlash.tracking import GearboxTracker

#: 2026-03-02 08:00:00.250 UTC, the recordings' start.
START = dt.datetime(2026, 3, 2, 8, 0, 0, 250000, tzinfo=dt.timezone.utc)
#: The same instant at UTC+01:00, as a recorder in Berlin writes it.
BERLIN = START.astimezone(dt.timezone(dt.timedelta(hours=1)))


@pytest.fixture(scope="module")
def rec():
    return simulate_rig(duration_s=20.0, play_deg=0.4, seed=3)


def first_chunk_origin(path, **options) -> tuple[float | None, str]:
    with open_log(path, **options) as log:
        next(iter(log.iter_chunks()))
        return log.time_origin_unix_s, log.time_origin_name


def write_tdms(path, rec, start):
    props = {"wf_increment": 1e-3, "wf_start_offset": 0.0, "unit_string": "deg"}
    if start is not None:
        props["wf_start_time"] = start
    with TdmsWriter(str(path)) as writer:
        writer.write_segment(
            [
                ChannelObject("Rig", "Motor", rec.motor_deg, properties=props),
                ChannelObject("Rig", "Load", rec.load_deg, properties=props),
            ]
        )
    return path


def write_parquet(path, rec, timestamps: bool):
    if timestamps:
        ticks = np.round((START.timestamp() + rec.time_s) * 1e6).astype(np.int64)
        time = pa.array(ticks, type=pa.timestamp("us", tz="UTC"))
    else:
        time = pa.array(rec.time_s)
    pq.write_table(pa.table({"time": time, "motor": rec.motor_deg, "load": rec.load_deg}), path)
    return path


MDF_COLUMNS = {"columns": {"motor": "Motor", "load": "Load"}}
TDMS_COLUMNS = {"columns": {"motor": "Rig/Motor", "load": "Rig/Load"}}


@pytest.mark.parametrize("start", [START, BERLIN], ids=["utc", "utc+1"])
def test_an_mdf4_header_start_time_is_the_files_clock(tmp_path, rec, start):
    path = rig_mdf(tmp_path / "rig.mf4", rec, start=start)
    origin, name = first_chunk_origin(path, **MDF_COLUMNS)
    assert origin == pytest.approx(START.timestamp(), abs=1e-6) and name == "MDF header start time"


def test_an_mdf4_header_in_local_time_without_zone_is_read_as_utc(tmp_path, rec):
    path = rig_mdf(tmp_path / "rig.mf4", rec, start=START.replace(tzinfo=None))
    assert first_chunk_origin(path, **MDF_COLUMNS)[0] == pytest.approx(START.timestamp(), abs=1e-6)


def test_a_tdms_wf_start_time_is_the_files_clock(tmp_path, rec):
    path = write_tdms(tmp_path / "rig.tdms", rec, np.datetime64(START.replace(tzinfo=None), "us"))
    assert first_chunk_origin(path, **TDMS_COLUMNS) == (
        pytest.approx(START.timestamp(), abs=1e-6),
        "TDMS wf_start_time",
    )
    plain = write_tdms(tmp_path / "plain.tdms", rec, None)
    assert first_chunk_origin(plain, **TDMS_COLUMNS) == (None, "")


def test_a_parquet_timestamp_column_is_the_files_clock(tmp_path, rec):
    path = write_parquet(tmp_path / "rig.parquet", rec, timestamps=True)
    assert first_chunk_origin(path) == (pytest.approx(START.timestamp(), abs=1e-6), "Parquet timestamp column")
    assert first_chunk_origin(write_parquet(tmp_path / "plain.parquet", rec, timestamps=False)) == (None, "")


@pytest.mark.parametrize("kind", ["mdf", "tdms", "parquet"])
def test_track_places_a_measurement_file_by_its_own_clock_not_its_mtime(tmp_path, capsys, rec, kind):
    path, columns = {
        "mdf": (rig_mdf(tmp_path / "rig.mf4", rec, start=BERLIN), "motor=Motor,load=Load"),
        "tdms": (
            write_tdms(tmp_path / "rig.tdms", rec, np.datetime64(START.replace(tzinfo=None), "us")),
            "motor=Rig/Motor,load=Rig/Load",
        ),
        "parquet": (write_parquet(tmp_path / "rig.parquet", rec, timestamps=True), "motor=motor,load=load"),
    }[kind]
    os.utime(path, (1.8e9, 1.8e9))  # copied much later: the modification time is not the recording's
    argv = [
        "track",
        str(path),
        "--ratio",
        "30",
        "--db",
        str(tmp_path / "w.db"),
        "--gearbox",
        "g",
        "--every",
        "2",
        "--json",
        "--columns",
        columns,
    ]
    assert main(argv) == 0, capsys.readouterr().err
    result = json.loads(capsys.readouterr().out)
    assert result["clock"] != CLOCK_MTIME
    with HistoryStore(tmp_path / "w.db") as store:
        (run,) = store.runs("g")
        first = store.estimates("g")[0]
    assert run.started_unix_s == pytest.approx(START.timestamp(), abs=1e-3)
    assert START.timestamp() < first.time_unix_s < START.timestamp() + 20.0


def test_the_start_from_the_file_name():
    assert (
        start_from_name("logs/gb7_2026-03-02_080000.csv", "%Y-%m-%d_%H%M%S")
        == dt.datetime(2026, 3, 2, 8, tzinfo=dt.timezone.utc).timestamp()
    )
    assert (
        start_from_name("rig_20260302T0800+0100.csv", "%Y%m%dT%H%M%z")
        == dt.datetime(2026, 3, 2, 7, tzinfo=dt.timezone.utc).timestamp()
    )
    with pytest.raises(LogFormatError, match=r"day1.csv: its name holds no start time in the form '%Y-%m-%d'"):
        start_from_name("day1.csv", "%Y-%m-%d")
    with pytest.raises(InvalidParameterError, match="no year"):
        start_from_name("x_08-00.csv", "%H-%M")
    assert suggest_name_pattern("a_2026-03-02_080000.csv", "a_2026-03-03_080000.csv") == "%Y-%m-%d_%H%M%S"
    assert suggest_name_pattern("a_2026-03-02.csv", "a_2026-03-03.csv") == "%Y-%m-%d"
    assert suggest_name_pattern("day1.csv", "day2.csv") is None


def copies(tmp_path, names):
    """Logs whose time starts at 0, written now (the same modification time, as a copy without times gives)."""
    paths = []
    for k, name in enumerate(names):
        paths.append(tmp_path / name)
        simulate_rig(duration_s=6.0, play_deg=0.3, seed=80 + k).write_csv(paths[-1])
        os.utime(paths[-1], (1.75e9, 1.75e9))
    return paths


def test_copies_placed_by_their_modification_time_are_refused_naming_both_and_the_option(tmp_path, capsys):
    logs = copies(tmp_path, ["gb7_2026-03-02_080000.csv", "gb7_2026-03-03_080000.csv"])
    db = tmp_path / "w.db"
    argv = ["track", *map(str, logs), "--ratio", "30", "--db", str(db), "--gearbox", "g", "--every", "2"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "gb7_2026-03-03_080000.csv: starts" in err and "inside " in err and "gb7_2026-03-02_080000.csv" in err
    assert "give --start-from-name '%Y-%m-%d_%H%M%S'" in err and "nothing was added" in err
    if db.exists():  # refused before anything was tracked
        with HistoryStore(db) as store:
            assert store.gearbox_ids() == []
    assert main([*argv, "--start-from-name", "%Y-%m-%d_%H%M%S", "--json"]) == 0
    results = [json.loads(part) for part in capsys.readouterr().out.replace("}\n{", "}\n\n{").split("\n\n")]
    assert [r["clock"] for r in results] == ["file name (%Y-%m-%d_%H%M%S)"] * 2
    with HistoryStore(db) as store:
        starts = [r.started_unix_s for r in store.runs("g")]
    assert np.diff(starts) == pytest.approx([86400.0])
    assert (
        main([*argv, "--start-from-name", "%Y-%m-%d_%H%M%S"]) == 0
    )  # tracked again: the same samples, already imported
    assert capsys.readouterr().out.count("already imported") == 2


def test_a_copy_without_dates_in_its_name_is_refused_with_every_way_to_place_it(tmp_path):
    first, second = copies(tmp_path, ["day1.csv", "day2.csv"])
    with HistoryStore(tmp_path / "w.db", create=True) as store:
        tracker = GearboxTracker(store, "g", 30.0, every_s=2.0)
        tracker.track_log(first)
        with pytest.raises(
            HistoryError,
            match=r"day2.csv: starts .* inside run 1 \(.*day1.csv.*--start-from-name PATTERN.*start = .*--start TIME",
        ):
            tracker.track_log(second)
        assert len(store.runs("g")) == 1


def test_a_manifest_gives_each_log_its_start(tmp_path, capsys):
    copies(tmp_path, ["a.csv", "b.csv"])
    manifest = tmp_path / "fleet.toml"
    manifest.write_text(
        '[defaults]\nratio = 30\nevery = 2\n\n[[gearbox]]\nid = "g"\n'
        'logs = [{ path = "b.csv", start = 2026-03-03T08:00:00Z }, { path = "a.csv", start = "2026-03-02T08:00:00" }]\n'
    )
    assert (
        main(["track", "--manifest", str(manifest), "--db", str(tmp_path / "w.db"), "--workers", "0", "--json"]) == 0
    ), capsys.readouterr().err
    with HistoryStore(tmp_path / "w.db") as store:
        runs = store.runs("g")
    assert [os.path.basename(r.source) for r in runs] == ["a.csv", "b.csv"]
    assert [r.started_unix_s for r in runs] == [
        dt.datetime(2026, 3, d, 8, tzinfo=dt.timezone.utc).timestamp() for d in (2, 3)
    ]
    manifest.write_text('[[gearbox]]\nid = "g"\nratio = 30\nlogs = [{ path = "a.csv", begin = 1 }]\n')
    assert main(["track", "--manifest", str(manifest), "--db", str(tmp_path / "w.db"), "--workers", "0"]) == 1
    assert "unknown key 'begin'" in capsys.readouterr().err


def test_a_millisecond_time_column_is_found_from_its_sample_period(tmp_path, capsys):
    rec = simulate_rig(duration_s=20.0, play_deg=0.3, seed=9)
    seconds, millis = tmp_path / "s.csv", tmp_path / "ms.csv"
    rec.write_csv(seconds)
    rec.time_s = rec.time_s * 1000.0  # milliseconds under the header "time"
    rec.write_csv(millis)
    common = ["--ratio", "30", "--gearbox", "g", "--every", "5", "--json", "--start", "2026-03-02T08:00:00"]
    assert main(["track", str(seconds), "--db", str(tmp_path / "s.db"), *common]) == 0
    capsys.readouterr()
    assert main(["track", str(millis), "--db", str(tmp_path / "ms.db"), *common]) == 0
    err = capsys.readouterr().err
    assert (
        "warning: " in err
        and "steps by 1 from sample to sample" in err
        and "read as ms (1000 Hz" in err
        and "--time-unit s" in err
    )
    rows = {}
    for name in ("s", "ms"):
        with HistoryStore(tmp_path / f"{name}.db") as store:
            rows[name] = [v for e in store.estimates("g") for v in (e.operating_hours, e.time_unix_s, e.backlash_deg)]
    assert len(rows["s"]) >= 6 and rows["ms"] == pytest.approx(rows["s"], rel=1e-9)
    assert main(["track", str(millis), "--db", str(tmp_path / "kept.db"), *common, "--time-unit", "s"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_the_time_unit_rule():
    with warnings.catch_warnings():
        warnings.simplefilter("error", BacklashWarning)
        assert time_unit_scale(np.arange(0.0, 10.0, 0.001)) == 1.0  # 1 kHz in seconds
        assert time_unit_scale(np.arange(0.0, 60.0, 0.1)) == 1.0  # 10 Hz: slow, but seconds
        assert time_unit_scale(np.floor(1.7e9 + np.arange(0.0, 5.0, 0.001))) == 1.0  # whole seconds stamped at 1 kHz
        assert time_unit_scale(np.arange(0.0, 1e4, 10.0), "ms") == 1e-3
    with pytest.warns(BacklashWarning, match="read as ms"):
        assert time_unit_scale(np.arange(1.7e12, 1.7e12 + 5000.0, 1.0)) == 1e-3  # UNIX time in milliseconds
    with pytest.warns(BacklashWarning, match="read as us"):
        assert time_unit_scale(np.arange(0.0, 1e6, 1000.0)) == 1e-6
