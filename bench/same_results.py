"""The outputs that speed work must not change, written to a folder: compare two folders with ``diff -r``.

Every output is the command's own (``online-backlash ...`` in a fresh process), byte for byte:

* ``estimate --json``, ``estimate --trace`` and ``diagnose --json`` of the three measured da Vinci runs
  (``../shared/data/davinci_tool_gearhead_backlash``, the call of the README) and ``track`` of each
  into a SQLite store (one gearbox per run, ``--start`` given, ``--every 10``);
* ``estimate --json`` of the bench logs: the simulated 30:1 rig (``--samples``, 1 kHz) written as
  Parquet (snappy, as ``bench/measurement_files.py`` writes it; uncompressed; LZ4), Arrow IPC, MDF4 and
  CSV, and the two-mass rig logs of ``bench/diagnose_speed.py`` (2 and 10 minutes, with torque; also
  ``diagnose --json`` of these two);
  ``estimate --trace`` and ``track`` of the MDF4 and the Parquet file;
* ``track --manifest`` of the fleet of ``bench/fleet.py`` (4 gearboxes x 3 logs x 120 s), serially
  and on a Dask ``LocalCluster`` of 2 workers.

A store is written out as JSON: every column of its estimates (ordered by gearbox and sample), of
its runs (but the time of the import) and each gearbox's checkpoint; ``id`` and ``run_id`` are left
out (a cluster numbers its runs in the order the gearboxes start).

    python bench/same_results.py OUT [--dir /tmp/online-backlash-same] [--samples 4000000] [--runs DIR]
    diff -r OUT_BEFORE OUT_AFTER && echo same
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "davinci_tool_gearhead_backlash"
DAVINCI = [
    "--ratio", "-35", "--columns", "time=time_s,motor=motor_counts,load=spindle_counts,torque=backend_torque_Nm",
    "--units", "counts", "--motor-cpr", "4096", "--load-cpr", "8192",
]  # fmt: skip
RIG = ["--ratio", "30"]
MDF_COLUMNS = ["--columns", "motor=Motor,load=Load"]
TWO_MASS = ["--ratio", "30", "--columns", "time=time,motor=motor,load=load,torque=torque"]


def bench_rig(samples: int, quick: bool = False):
    """The simulated 30:1 rig the speed benches read: ``samples`` at 1 kHz, play 0.5 deg, seed 3; ``quick``: reversing
    every 0.2-0.4 s (a short file whose samples start the estimator)."""
    from online_backlash.simulation.rig import simulate_rig

    return simulate_rig(
        duration_s=samples / 1000.0, play_deg=0.5, seed=3, **({"reversal_s": (0.2, 0.4)} if quick else {})
    )


def write_rig_formats(rec, parquet: dict[str, Path], arrow: Path, mf4: Path, csv: Path) -> None:
    """The rig record ``rec`` (time, motor, load) as Parquet (``parquet``: compression -> path; row groups of
    1,000,000 rows), Arrow IPC (uncompressed, batches of 1,000,000 rows), MDF 4.10 (asammdf; ``Motor`` and ``Load``
    in one channel group) and CSV: the files the speed benches read (also ``bench/end_to_end.py``)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from asammdf import MDF, Signal

    table = pa.table({"time": rec.time_s, "motor": rec.motor_deg, "load": rec.load_deg})
    for compression, path in parquet.items():
        pq.write_table(table, path, row_group_size=1_000_000, compression=compression)
    with pa.OSFile(str(arrow), "wb") as sink, pa.ipc.new_file(sink, table.schema) as writer:
        for batch in table.to_batches(max_chunksize=1_000_000):
            writer.write_batch(batch)
    mdf = MDF(version="4.10")
    mdf.append(
        [
            Signal(rec.motor_deg, rec.time_s, name="Motor", unit="deg"),
            Signal(rec.load_deg, rec.time_s, name="Load", unit="deg"),
        ]
    )
    mdf.save(mf4, overwrite=True)
    mdf.close()
    rec.write_csv(csv)


def write_inputs(folder: Path, samples: int) -> dict[str, Path]:
    """The bench logs in ``folder`` (written once, kept between runs)."""
    folder.mkdir(parents=True, exist_ok=True)
    stem = folder / f"rig-{samples}"
    paths = {
        "parquet": stem.with_suffix(".parquet"), "uncompressed.parquet": folder / f"rig-{samples}-uncompressed.parquet",
        "lz4.parquet": folder / f"rig-{samples}-lz4.parquet", "arrow": stem.with_suffix(".arrow"),
        "mf4": stem.with_suffix(".mf4"), "csv": stem.with_suffix(".csv"),
        "two_mass_2min": folder / "two_mass_2min.csv", "two_mass_10min": folder / "two_mass_10min.csv",
    }  # fmt: skip
    if all(p.exists() for p in paths.values()):
        return paths
    from online_backlash.simulation.two_mass_rig import simulate_two_mass

    parquet = {"snappy": paths["parquet"], "none": paths["uncompressed.parquet"], "lz4": paths["lz4.parquet"]}
    write_rig_formats(bench_rig(samples), parquet, paths["arrow"], paths["mf4"], paths["csv"])
    for minutes in (2, 10):
        simulate_two_mass(duration_s=60.0 * minutes, motion="rig", coulomb_nm=0.05, seed=0).write_csv(
            paths[f"two_mass_{minutes}min"]
        )
    return paths


def cli(out: Path, name: str, argv: list[str]) -> None:
    """``online-backlash ARGV``; its stdout (and exit code, if not 0) to ``out/name``."""
    command = [
        sys.executable,
        "-c",
        "import sys; from online_backlash.cli import main; sys.exit(main(sys.argv[1:]))",
        *argv,
    ]
    done = subprocess.run(command, capture_output=True, text=True)
    text = done.stdout + ("" if done.returncode == 0 else f"\nexit {done.returncode}\n{done.stderr}")
    (out / name).write_text(text)


def dump_store(db: Path, target: Path) -> None:
    """Every estimate, run and checkpoint of a SQLite store as JSON (ids and import times left out)."""
    import sqlite3

    con = sqlite3.connect(db)
    con.row_factory = sqlite3.Row
    estimates = [
        {k: row[k] for k in row.keys() if k not in ("id", "run_id")}
        for row in con.execute("SELECT * FROM estimates ORDER BY gearbox_id, n_samples, time_unix_s")
    ]
    runs = [
        {k: row[k] for k in row.keys() if k not in ("id", "imported_unix_s")}
        for row in con.execute("SELECT * FROM runs ORDER BY gearbox_id, started_unix_s, source")
    ]
    gearboxes = {}
    for row in con.execute("SELECT id, ratio, limit_arcmin, checkpoint FROM gearboxes ORDER BY id"):
        checkpoint = json.loads(row["checkpoint"]) if row["checkpoint"] else None
        if checkpoint is not None:
            checkpoint.pop("run_id", None)
        gearboxes[row["id"]] = {"ratio": row["ratio"], "limit_arcmin": row["limit_arcmin"], "checkpoint": checkpoint}
    con.close()
    target.write_text(
        json.dumps({"estimates": estimates, "runs": runs, "gearboxes": gearboxes}, indent=1, sort_keys=True)
    )


def track(out: Path, work: Path, name: str, argv: list[str], keep_stdout: bool = True) -> None:
    """``track`` into a fresh store, the store written to ``out/name.json`` (and what it printed to ``name.stdout``)."""
    db = work / f"{name}.db"
    for p in work.glob(f"{name}.db*"):
        p.unlink()
    cli(out if keep_stdout else work, f"{name}.stdout", ["track", *argv, "--db", str(db), "--quiet"])
    dump_store(db, out / f"{name}.json")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="folder for the outputs (created)")
    ap.add_argument("--dir", type=Path, default=Path("/tmp/online-backlash-same"), help="where the bench logs are kept")
    ap.add_argument("--samples", type=int, default=4_000_000, help="samples of the simulated rig's files")
    ap.add_argument("--runs", type=Path, default=SHARED, help="the measured da Vinci runs (a tree elsewhere: give it)")
    args = ap.parse_args()
    started = time.perf_counter()
    out, work = args.out, args.dir / "work"
    out.mkdir(parents=True, exist_ok=True)
    work.mkdir(parents=True, exist_ok=True)
    paths = write_inputs(args.dir, args.samples)
    runs = sorted(args.runs.glob("*.csv"))
    if not runs:
        raise SystemExit(f"no measured runs (*.csv) in {args.runs}")
    for run in runs:
        cli(out, f"{run.stem}.estimate.json", ["estimate", str(run), *DAVINCI, "--json"])
        cli(out, f"{run.stem}.diagnose.json", ["diagnose", str(run), *DAVINCI, "--json"])
        trace = work / f"{run.stem}.trace.csv"
        cli(out, f"{run.stem}.trace.stdout", ["estimate", str(run), *DAVINCI, "--json", "--trace", str(trace)])
        (out / f"{run.stem}.trace.csv").write_bytes(trace.read_bytes())
        track(
            out,
            work,
            f"{run.stem}.track",
            [str(run), *DAVINCI, "--gearbox", run.stem, "--start", "2026-01-05T08:00:00", "--every", "10"],
        )
    for kind, path in paths.items():
        options = TWO_MASS if kind.startswith("two_mass") else RIG + (MDF_COLUMNS if kind == "mf4" else [])
        cli(out, f"{kind}.estimate.json", ["estimate", str(path), *options, "--json"])
        if kind.startswith("two_mass"):
            cli(out, f"{kind}.diagnose.json", ["diagnose", str(path), *options, "--json"])
        if kind in ("parquet", "mf4"):
            trace = work / f"{kind}.trace.csv"
            cli(
                out,
                f"{kind}.trace.stdout",
                ["estimate", str(path), *options, "--json", "--trace", str(trace), "--every", "10"],
            )
            (out / f"{kind}.trace.csv").write_bytes(trace.read_bytes())
            track(
                out,
                work,
                f"{kind}.track",
                [str(path), *options, "--gearbox", kind, "--start", "2026-01-05T08:00:00", "--every", "60"],
            )
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    from online_backlash.fleet.simulated import write_simulated_fleet

    manifest = write_simulated_fleet(args.dir / "fleet", 4, 3, 120.0, every_s=10.0)
    for workers in ("0", "2"):
        # (a cluster's run ids follow the order the gearboxes start in: its printed results are not kept)
        track(
            out,
            work,
            f"fleet-workers{workers}",
            ["--manifest", str(manifest), "--workers", workers, "--json"],
            workers == "0",
        )
    print(f"{len(list(out.iterdir()))} outputs in {out} ({time.perf_counter() - started:.0f} s)")


if __name__ == "__main__":
    main()
