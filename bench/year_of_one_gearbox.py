"""A year of one gearbox at 1 kHz (3.2e10 samples), projected from ``track`` of a measured hour (issue 31 item 5).

The simulated 30:1 rig (1 kHz, play 0.5 deg): one hour (3,600,000 samples) and a 2,000-sample file of the same rig,
written once as CSV, Parquet (snappy, pyarrow's default) and MDF4 (``same_results.write_rig_formats``). Then
``--rounds`` times, one process at a time in the same order: ``online-backlash track FILE --ratio 30 --gearbox g
--start 2026-01-05T08:00:00 --db FRESH.db --quiet`` (``--every`` 60 s: one stored estimate a minute) of each file,
each a fresh process: wall, CPU (user + system, all threads) and peak RSS (``bench/end_to_end.py``'s ``run``), and the
store's size. An hour costs (BIG - SMALL): start-up cancels, paid once per process, not per hour. The year is
8,889 such hours (3.2e10 / 3.6e6): CPU and store size scale with the samples (the reader streams blocks, the
estimator's state is fixed in size), peak RSS does not (it is the process's, flat in the log's length).

    python bench/year_of_one_gearbox.py [--dir /tmp/online-backlash-year] [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
from pathlib import Path

from end_to_end import ESTIMATE, run, spread  # (this folder)
from same_results import bench_rig, write_rig_formats

HOUR = 3_600_000
SMALL = 2000
YEAR = 3.2e10
FORMATS = {"csv": ".csv", "parquet": ".parquet", "mf4": ".mf4"}
OPTIONS = {"csv": [], "parquet": [], "mf4": ["--columns", "motor=Motor,load=Load"]}


def write_files(folder: Path) -> dict[str, tuple[Path, Path]]:
    """format -> (hour file, 2,000-sample file), written once into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = {kind: (folder / f"hour{suffix}", folder / f"small{suffix}") for kind, suffix in FORMATS.items()}
    if all(p.exists() for pair in paths.values() for p in pair):
        return paths
    records = (bench_rig(HOUR), bench_rig(SMALL, quick=True))
    for which, rec in enumerate(records):
        names = [paths[kind][which] for kind in ("parquet", "csv", "mf4")]
        arrow = folder / "unused.arrow"
        write_rig_formats(rec, {"snappy": names[0]}, arrow, names[2], names[1])
        arrow.unlink()
    return paths


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", type=Path, default=Path("/tmp/online-backlash-year"), help="where the files are kept")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    paths = write_files(args.dir)
    runs: dict[str, list[dict]] = {}
    load = [os.getloadavg()[0]]
    for _ in range(args.rounds):
        for kind in FORMATS:
            for size, path in zip(("hour", "small"), paths[kind]):
                db = args.dir / f"{kind}-{size}.db"
                for p in args.dir.glob(f"{db.name}*"):
                    p.unlink()
                argv = ["track", str(path), "--ratio", "30", *OPTIONS[kind], "--gearbox", "g"]
                argv += ["--start", "2026-01-05T08:00:00", "--db", str(db), "--quiet"]
                result = run(ESTIMATE, *argv)
                result["db_kb"] = sum(p.stat().st_size for p in args.dir.glob(f"{db.name}*")) / 1024  # (and its WAL)
                runs.setdefault(f"{kind} {size}", []).append(result)
        load.append(os.getloadavg()[0])
    hours = YEAR / HOUR
    print(
        f"{os.cpu_count()} cores ({platform.machine()}), Python {platform.python_version()}; {args.rounds} rounds; "
        f"load average {min(load):.1f}-{max(load):.1f} (1 min, at each round's start and the end)\n"
    )
    print(
        "| file | track of an hour: wall s | CPU s | an hour's CPU s (hour - small) | store kB an hour "
        "| peak RSS hour / small, MB | a year (3.2e10 samples): CPU h | store GB |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for kind in FORMATS:
        big, small = runs[f"{kind} hour"], runs[f"{kind} small"]
        cpu = [b["cpu"] - s["cpu"] for b, s in zip(big, small)]
        store = statistics.median(b["db_kb"] - s["db_kb"] for b, s in zip(big, small))
        print(
            f"| {kind} | {spread([b['wall'] for b in big])} | {spread([b['cpu'] for b in big])} | {spread(cpu)} "
            f"| {store:.0f} | {max(b['rss_mb'] for b in big):.0f} / {max(s['rss_mb'] for s in small):.0f} "
            f"| {spread([c * hours / 3600 for c in cpu], '{:.1f}')} | {store * hours / 2**20:.2f} |"
        )


if __name__ == "__main__":
    main()
