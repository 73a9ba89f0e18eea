"""The fleet (issue 14, items 1, 2, 7): the manifest, Dask workers equal to serial tracking (a worker
killed mid-log included), and a history that logs cannot fool (identity by samples, time order,
overlaps, a listen --raw-log folder)."""

from __future__ import annotations

import dataclasses
import gzip
import json
import os
import platform
import shutil
import subprocess
import sys
import threading
import time

import pytest
from live_run import kill_mid_work, run_live, send_frames, wait_until
from rig_can import RIG_CAN

from online_backlash.cli import main
from online_backlash.cli.track import track_gearbox
from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.errors import HistoryError
from online_backlash.fleet import GearboxOutcome, load_manifest, run_fleet
from online_backlash.fleet.progress import FleetProgress
from online_backlash.fleet.simulated import write_simulated_fleet
from online_backlash.history.store import HistoryStore
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.rig_logs import rig_can_frames
from online_backlash.tracking import CLOCK_MTIME, GearboxTracker, TrackResult

DAY = 86400.0
T0 = 1.7e9  # logs carry UNIX times


def store_contents(db):
    """Every gearbox's runs, estimates and checkpoint, without the store's own run ids."""
    with HistoryStore(db) as store:
        out = {}
        for gearbox_id in store.gearbox_ids():
            runs = {r.id: r.source for r in store.runs(gearbox_id)}
            run_rows = [
                (r.source, r.log_sha256, r.status, r.started_unix_s, r.ended_unix_s, r.samples_done, r.samples, r.gaps)
                for r in store.runs(gearbox_id)
            ]
            estimates = [{**dataclasses.asdict(e), "run_id": runs[e.run_id]} for e in store.estimates(gearbox_id)]
            checkpoint = dict(store.gearbox(gearbox_id).checkpoint)
            checkpoint.pop("run_id")
            out[gearbox_id] = (sorted(run_rows), estimates, json.dumps(checkpoint, sort_keys=True))
    return out


def json_objects(text):
    """The JSON objects printed one after another."""
    decoder, found, at = json.JSONDecoder(), [], 0
    while text[at:].strip():
        obj, at = decoder.raw_decode(text, at + len(text[at:]) - len(text[at:].lstrip()))
        found.append(obj)
    return found


# -- the manifest ---------------------------------------------------------------------------------


def manifest_error(tmp_path, capsys, text, *extra):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    assert main(["track", "--manifest", str(path), "--db", str(tmp_path / "x.db"), "--workers", "0", *extra]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "Traceback" not in err and err.count("\n") == 1
    return err


def test_manifest_errors_name_the_file_the_gearbox_and_the_key(tmp_path, capsys):
    write_simulated_fleet(tmp_path, gearboxes=1, logs=1)
    ok = '[[gearbox]]\nid = "GB-0"\nratio = 30\nlogs = "gb0/*.csv"\n'
    err = manifest_error(tmp_path, capsys, ok + "limit_arcmins = 21\n")
    assert "bad.toml: [[gearbox]] #1 (id 'GB-0'): unknown key 'limit_arcmins'; did you mean 'limit_arcmin'?" in err
    err = manifest_error(tmp_path, capsys, ok + 'units = "furlongs"\n')  # checked by track's own parser
    assert "bad.toml: [[gearbox]] #1 (id 'GB-0'): argument --units: invalid choice: 'furlongs'" in err
    err = manifest_error(tmp_path, capsys, '[[gearbox]]\nid = "GB-0"\nlogs = "gb0/*.csv"\n')  # no ratio
    assert "(id 'GB-0'): give --gearbox ID and --ratio R" in err
    err = manifest_error(tmp_path, capsys, "[defaults]\nratio = 30\nevry = 5\n" + ok)
    assert "bad.toml: [defaults]: unknown key 'evry'; did you mean 'every'?" in err
    assert "bad.toml:3: not valid TOML" in manifest_error(tmp_path, capsys, "[defaults]\nratio = 30\nevery = = 5\n")
    assert "'db' is not a per-gearbox option" in manifest_error(tmp_path, capsys, ok + 'db = "other.db"\n')
    # every option of the live and fleet groups is the command's, read from track's parser (not a list kept beside it)
    for key in ("mqtt_ca", "raw_log", "workers"):
        assert f"'{key}' is not a per-gearbox option" in manifest_error(tmp_path, capsys, ok + f'{key} = "x"\n')
    assert "nothing matches 'gb9/*.csv'" in manifest_error(tmp_path, capsys, ok.replace("gb0", "gb9"))
    assert "the id 'GB-0' is given twice" in manifest_error(tmp_path, capsys, ok + ok)
    assert "no [[gearbox]] tables" in manifest_error(tmp_path, capsys, "[defaults]\nratio = 30\n")
    assert "--every: with --manifest, per-gearbox options go into the manifest" in manifest_error(
        tmp_path, capsys, ok, "--every", "5"
    )
    assert "not both" in manifest_error(tmp_path, capsys, ok, "--scheduler", "tcp://127.0.0.1:1")  # with --workers 0


def test_a_gearbox_that_fails_stops_alone(tmp_path, capsys):
    manifest = write_simulated_fleet(tmp_path, gearboxes=2, logs=1)
    (tmp_path / "gb1" / "day00.csv").write_text("when,a,b\n0,1,2\n")  # a log without the columns
    assert main(["track", "--manifest", str(manifest), "--db", str(tmp_path / "w.db"), "--workers", "0"]) == 1
    out, err = capsys.readouterr()
    assert f"error: {manifest}: gearbox GB-1: {tmp_path / 'gb1' / 'day00.csv'}" in err and "Traceback" not in err
    assert "fleet: 1 of 2 gearboxes tracked, 1 logs" in out
    with HistoryStore(tmp_path / "w.db") as store:
        assert store.gearbox_ids() == ["GB-0"] and store.estimates("GB-0")


def test_fleet_options_need_a_manifest(tmp_path, capsys, two_days):
    argv = [
        "track",
        str(two_days[0]),
        "--db",
        str(tmp_path / "w.db"),
        "--gearbox",
        "g1",
        "--ratio",
        "30",
        "--workers",
        "2",
    ]
    assert main(argv) == 1
    assert capsys.readouterr().err == "error: --workers and --scheduler run a fleet: give them with --manifest\n"


def test_the_progress_bar_counts_gearboxes_and_samples(capsys):
    with FleetProgress(3, show=True) as bar:
        for n in (1000, 3000):
            bar.done(GearboxOutcome("g", results=[TrackResult("g", 1, "x", samples_fed=n)]))
        assert bar.samples == 4000 and bar.samples_per_s > 0
    err = capsys.readouterr().err
    assert "fleet" in err and "2/3" in err and "samples/s" in err
    with FleetProgress(3, show=False) as quiet:
        quiet.done(GearboxOutcome("g"))
    assert capsys.readouterr().err == ""


def test_manifest_keys_are_track_options_with_underscores(tmp_path):
    write_simulated_fleet(tmp_path, gearboxes=1, logs=2)
    path = tmp_path / "m.toml"
    path.write_text(
        '[defaults]\nratio = -30\nskip_bad_rows = true\ndiagnose = false\n\n[[gearbox]]\nid = "GB-0"\n'
        'logs = ["gb0/day01.csv", "gb0/day00.csv"]\n'
        'columns = { time = "time_s", motor = "motor_deg", load = "load_deg" }\nwarn_arcmin = 18\n'
        "limit_arcmin = 21\nmemory_reversals = 40\n"
    )
    seen = []

    def parse(argv):
        seen.append(argv)
        return argv

    (job,) = load_manifest(
        path,
        "w.db",
        parse,
        {"ratio", "skip_bad_rows", "diagnose", "columns", "warn_arcmin", "limit_arcmin", "memory_reversals"},
        (),
    )
    assert job.id == "GB-0" and job.logs == (str(tmp_path / "gb0" / "day01.csv"), str(tmp_path / "gb0" / "day00.csv"))
    assert seen == [list(job.argv)]
    assert job.argv == (
        "--db", "w.db", "--gearbox=GB-0", "--ratio=-30", "--skip-bad-rows",
        "--columns=time=time_s,motor=motor_deg,load=load_deg", "--warn-arcmin=18", "--limit-arcmin=21",
        "--memory-reversals=40", "--", *job.logs,
    )  # fmt: skip


# -- Dask against serial ---------------------------------------------------------------------------


@pytest.mark.slow
def test_two_dask_workers_give_the_rows_of_serial_tracking(tmp_path, capsys):
    manifest = write_simulated_fleet(tmp_path)
    serial, parallel = tmp_path / "serial.db", tmp_path / "dask.db"
    assert main(["track", "--manifest", str(manifest), "--db", str(serial), "--workers", "0"]) == 0
    out = capsys.readouterr()
    assert "fleet: 3 of 3 gearboxes tracked, 6 logs, 120000 samples" in out.out and "serially" in out.out
    assert main(["track", "--manifest", str(manifest), "--db", str(parallel), "--workers", "2", "--json"]) == 0
    out = capsys.readouterr()
    assert out.err.count("SQLite store: the workers' writes are serialised") == 1
    reports = json_objects(out.out)
    assert len(reports) == 6 and {r["gearbox_id"] for r in reports} == {"GB-0", "GB-1", "GB-2"}
    assert store_contents(parallel) == store_contents(serial)
    assert all(
        {e["run_id"] for e in rows[1]} == {r[0] for r in rows[0]} for rows in store_contents(serial).values()
    )  # estimates from every log
    # run again: every log is already imported, nothing changes
    assert main(["track", "--manifest", str(manifest), "--db", str(parallel), "--workers", "2"]) == 0
    assert capsys.readouterr().out.count("already imported") == 6
    assert store_contents(parallel) == store_contents(serial)


@pytest.mark.slow
def test_a_dask_scheduler_and_two_dask_workers_give_the_rows_of_serial_tracking(tmp_path, capsys):
    """``dask scheduler`` and two ``dask worker tcp://...`` processes, started as a user starts them (issue 31 item 3):
    ``track --manifest --scheduler`` on them stores what serial tracking stores."""
    from dask.distributed import Client

    manifest = write_simulated_fleet(tmp_path / "fleet", gearboxes=4, logs=2, duration_s=30.0, every_s=5.0)
    serial, parallel = tmp_path / "serial.db", tmp_path / "dask.db"
    assert main(["track", "--manifest", str(manifest), "--db", str(serial), "--workers", "0"]) == 0
    dask = [sys.executable, "-m", "dask"]
    scheduler_file = tmp_path / "scheduler.json"
    quiet = {
        "stdout": subprocess.DEVNULL,
        "stderr": subprocess.DEVNULL,
        "cwd": tmp_path,
    }  # the installed package, not src/
    processes = [subprocess.Popen([*dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                   "--scheduler-file", str(scheduler_file)], **quiet)]  # fmt: skip
    try:
        with Client(scheduler_file=str(scheduler_file), timeout=120) as client:  # waits for the scheduler's file
            address = client.scheduler.address
            assert address.startswith("tcp://127.0.0.1:")
            for name in ("w1", "w2"):
                worker = [*dask, "worker", address, "--nthreads", "1", "--name", name, "--no-dashboard"]
                processes.append(subprocess.Popen([*worker, "--local-directory", str(tmp_path / name)], **quiet))
            client.wait_for_workers(2, timeout=120)
            capsys.readouterr()
            assert main(["track", "--manifest", str(manifest), "--db", str(parallel), "--scheduler", address]) == 0
            assert "4 of 4 gearboxes tracked, 8 logs, 240000 samples" in capsys.readouterr().out
            workers = {w["name"] for w in client.scheduler_info()["workers"].values()}
        assert workers == {"w1", "w2"}
    finally:
        for process in reversed(processes):
            process.terminate()
            process.wait(timeout=60)
    assert store_contents(parallel) == store_contents(serial)


KEPT_AFTER_A_TASK = """
import os, sys
import numpy as np
from online_backlash.cli.track import parse_track_argv, track_command_line_options, track_defaults, track_gearbox
from online_backlash.fleet import load_manifest
from online_backlash.history.store import HistoryStore

def resident_mb():
    return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20

(job,) = load_manifest(sys.argv[1], sys.argv[2], parse_track_argv, track_defaults(), track_command_line_options())
with HistoryStore(sys.argv[2], create=True):
    pass
assert track_gearbox(job).error is None
before = resident_mb()
block = np.ones(8 << 20)  # 64 MB, freed at once
del block
print(resident_mb() - before)
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's allocator and its environment variable")
def test_a_fleet_task_keeps_freed_memory_in_a_worker_started_as_dask_starts_it(tmp_path):
    """Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which returned every large block a log's
    reading freed to the kernel (1.6-1.7x the CPU of the same gearbox in the CLI's process, page faults): after a
    fleet task the process keeps a freed 64 MB block for the next one."""
    manifest = write_simulated_fleet(tmp_path, gearboxes=1, logs=1, duration_s=12.0)
    env = {**os.environ, "MALLOC_TRIM_THRESHOLD_": "65536"}
    argv = [sys.executable, "-c", KEPT_AFTER_A_TASK, str(manifest), str(tmp_path / "w.db")]
    done = subprocess.run(argv, env=env, capture_output=True, text=True, check=True, cwd=tmp_path)
    assert float(done.stdout) > 60


@pytest.mark.slow
@pytest.mark.postgres
def test_a_worker_killed_mid_log_loses_nothing(tmp_path, postgres_db):
    from dask.distributed import Client, LocalCluster

    # logs long enough (300 estimates each) that one is still being tracked after its first transactions
    manifest = write_simulated_fleet(tmp_path, gearboxes=2, logs=2, duration_s=600.0, every_s=2.0)
    serial = tmp_path / "serial.db"
    parse_only = load_manifest(manifest, str(serial), lambda argv: argv, {"ratio", "every", "limit_arcmin"}, ())
    run_fleet(parse_only, track_gearbox, workers=0)
    jobs = load_manifest(manifest, postgres_db, lambda argv: argv, {"ratio", "every", "limit_arcmin"}, ())
    with HistoryStore(postgres_db, create=True):
        pass
    killed = []
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster,
        Client(cluster) as client,
    ):
        pids = client.run(os.getpid)

        def kill_when_mid_log():
            # GB-0's first log has committed an estimate, not all: SIGKILL its worker (stopped while looked at)
            def gb0_worker():
                return next((address for address, keys in client.processing().items() if "track-GB-0" in keys), None)

            wait_until(gb0_worker, "a worker took GB-0")
            with HistoryStore(postgres_db) as store:

                def mid_log() -> bool:
                    runs = store.runs("GB-0") if "GB-0" in store.gearbox_ids() else []
                    mid = [r for r in runs if r.status == "running" and r.samples_done > 0]
                    killed[:] = [(mid[0].source, mid[0].samples_done)] if mid else []
                    return bool(mid)

                kill_mid_work(pids[gb0_worker()], mid_log, "GB-0's first log mid-way")

        killer = threading.Thread(target=kill_when_mid_log)
        killer.start()
        outcomes = run_fleet(jobs, track_gearbox, scheduler=cluster.scheduler_address)
        killer.join()
    assert killed, "the worker was not killed mid-log"
    gb0 = outcomes[0]
    (resumed,) = [r for r in gb0.results if r.source == killed[0][0]]
    assert (
        gb0.error is None and resumed.resumed_from >= killed[0][1] > 0
    )  # the retried task resumed from its checkpoint
    assert str(gb0.worker) != "" and all(o.error is None for o in outcomes)
    assert store_contents(postgres_db) == store_contents(serial)


# -- a history that cannot be fooled ----------------------------------------------------------------


@pytest.fixture
def two_days(tmp_path):
    paths = []
    for k in range(2):
        rec = simulate_rig(duration_s=24.0, play_deg=0.3, seed=50 + k)
        rec.time_s = rec.time_s + T0 + k * DAY
        paths.append(tmp_path / f"day{k}.csv")
        rec.write_csv(paths[-1])
    return paths


def tracker(store):
    return GearboxTracker(store, "g1", 30.0, every_s=3.0)


def test_a_log_is_its_samples_compressed_copies_and_fixed_rows_included(tmp_path, two_days):
    db = tmp_path / "w.db"
    zipped = tmp_path / "copy" / "day0.csv.gz"
    zipped.parent.mkdir()
    zipped.write_bytes(gzip.compress(two_days[0].read_bytes()))
    fixed = tmp_path / "fixed.csv"  # the same recording, one late row's value rewritten (as after fixing a bad row)
    lines = two_days[0].read_text().splitlines(keepends=True)
    cells = lines[9000].split(",")
    lines[9000] = ",".join([*cells[:-1], f"{float(cells[-1]) + 1e-3:.6f}\n"])
    fixed.write_text("".join(lines))
    with HistoryStore(db, create=True) as store:
        first = tracker(store).track_log(two_days[0])
        again = [tracker(store).track_log(p) for p in (zipped, fixed)]
        assert first.estimates_added > 0 and all(r.already_imported and r.estimates_added == 0 for r in again)
        assert len(store.runs("g1")) == 1 and len(store.estimates("g1")) == first.estimates_added


def test_an_overlapping_or_older_log_is_refused_naming_the_run(tmp_path, two_days):
    early = tmp_path / "early_changed.csv"  # the first log with its first rows changed: another log, same time range
    lines = two_days[0].read_text().splitlines(keepends=True)
    cells = lines[1].split(",")
    lines[1] = ",".join([*cells[:-1], f"{float(cells[-1]) + 1e-3:.6f}\n"])
    early.write_text("".join(lines))
    with HistoryStore(tmp_path / "w.db", create=True) as store:
        tracker(store).track_log(two_days[1])
        before = store.estimates("g1")
        with pytest.raises(
            HistoryError,
            match=r"day0.csv: starts 2023-11-14 22:13:20 UTC by the UNIX time column, before run 1 \(.*day1.csv",
        ):
            tracker(store).track_log(two_days[0])
        with pytest.raises(HistoryError, match=r"early_changed.csv: starts .*, before run 1"):
            tracker(store).track_log(early)
    with HistoryStore(tmp_path / "v.db", create=True) as store:
        tracker(store).track_log(two_days[0])
        with pytest.raises(
            HistoryError, match=r"early_changed.csv: starts .* inside run 1 \(.*day0.csv.*\) already tracked"
        ):
            tracker(store).track_log(early)
        assert len(store.runs("g1")) == 1
    assert before  # nothing was added by the refused logs (checked by the run count above)


def test_logs_placed_by_modification_time_that_overlap_are_refused(tmp_path):
    paths = []
    for k in range(2):  # device clocks starting at 0, both files written now: their mtimes place them together
        rec = simulate_rig(duration_s=12.0, play_deg=0.3, seed=60 + k)
        paths.append(tmp_path / f"dev{k}.csv")
        rec.write_csv(paths[-1])
    now = time.time()
    os.utime(paths[0], (now - 5.0, now - 5.0))
    os.utime(paths[1], (now, now))
    with HistoryStore(tmp_path / "w.db", create=True) as store:
        result = tracker(store).track_log(paths[0])
        assert result.clock == CLOCK_MTIME
        refusal = r"dev1.csv: starts .* by the file modification time, inside run 1 \(.*dev0.csv.*--start-from-name.*"
        refusal += "--start TIME"
        with pytest.raises(HistoryError, match=refusal):
            tracker(store).track_log(paths[1])


def test_track_sorts_the_logs_of_one_call_by_their_first_sample(tmp_path, capsys, two_days):
    common = ["--ratio", "30", "--gearbox", "g1", "--every", "3"]
    assert main(["track", str(two_days[1]), str(two_days[0]), "--db", str(tmp_path / "a.db"), *common]) == 0
    assert "logs tracked in the order of their first samples' time" in capsys.readouterr().err
    assert main(["track", *map(str, two_days), "--db", str(tmp_path / "b.db"), *common]) == 0
    assert store_contents(tmp_path / "a.db") == store_contents(tmp_path / "b.db")
    assert main(["track", str(two_days[0]), "--db", str(tmp_path / "c.db"), *common]) == 0
    capsys.readouterr()
    assert main(["track", str(two_days[0]).replace("day0", "day1"), "--db", str(tmp_path / "c.db"), *common]) == 0
    with HistoryStore(tmp_path / "c.db") as store:
        hours = [e.operating_hours for e in store.estimates("g1")]
    assert hours == sorted(hours)  # never a negative use


def test_track_takes_the_raw_log_folder_listen_wrote(tmp_path, capsys):
    rec = simulate_rig(duration_s=16.0, rate_hz=1000.0, seed=12)
    frames = list(rig_can_frames(rec, DbcDecoder(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count"), T0))
    can_opts = [*RIG_CAN, "--ratio", "30"]

    raw = tmp_path / "raw"
    argv = ["listen", "can", "--interface", "virtual", "--channel", "fleet-raw", *can_opts, "--raw-log", raw, "--json"]
    assert run_live(argv, lambda _: send_frames("fleet-raw", frames)) == 0
    live = json.loads(capsys.readouterr().out)
    assert live["samples"] == rec.time_s.size and any(raw.iterdir())
    track = ["track", str(raw), *can_opts, "--gearbox", "g1", "--every", "2", "--json"]
    assert main([*track, "--db", str(tmp_path / "w.db")]) == 0
    (result,) = [json.loads(capsys.readouterr().out)]
    assert result["samples_fed"] == live["samples"] and result["clock"] == "UNIX time column"
    copy = tmp_path / "copy"
    shutil.copytree(raw, copy)
    track[1] = str(copy)
    assert main([*track, "--db", str(tmp_path / "w.db")]) == 0  # a copy of the folder: the same log, already imported
    assert json.loads(capsys.readouterr().out)["already_imported"]


def test_runs_of_an_older_store_keyed_by_the_files_bytes_are_found(tmp_path, two_days):
    """A store written when a log's key was its file's SHA-256: its interrupted run resumes, its complete one is
    complete."""
    from online_backlash.replay import open_log
    from online_backlash.tracking import file_sha256, log_clock

    class Stop(Exception):
        pass

    def stop(samples, backlash):
        if samples > 10_000:
            raise Stop

    def legacy_track(store, path, progress=None):
        with open_log(path) as reader:
            clock = lambda first: log_clock(path, first)  # noqa: E731
            return tracker(store).track_chunks(
                reader.iter_chunks(), str(path), key=file_sha256(path), clock_offset=clock, progress=progress
            )

    with HistoryStore(tmp_path / "w.db", create=True) as store:
        legacy_track(store, two_days[0])
        with pytest.raises(Stop):
            legacy_track(store, two_days[1], progress=stop)
        assert tracker(store).track_log(two_days[0]).already_imported
        resumed = tracker(store).track_log(two_days[1])
        assert resumed.resumed_from > 10_000 and len(store.runs("g1")) == 2
        rows = [dataclasses.asdict(e) for e in store.estimates("g1")]
    with HistoryStore(tmp_path / "v.db", create=True) as store:
        for path in two_days:
            tracker(store).track_log(path)
        assert rows == [dataclasses.asdict(e) for e in store.estimates("g1")]
