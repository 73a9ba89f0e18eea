"""``estimate`` end to end on 10 million samples from Parquet and from MDF4, beside ``learn_many``.

The simulated 30:1 rig (:func:`online_backlash.simulation.rig.simulate_rig`, 1 kHz, play 0.5 deg) is
written once as a Parquet file (pyarrow, row groups of 1,000,000) and as an MDF 4.10 file
(asammdf, motor and load in one channel group). Each case then runs in a fresh interpreter:

* ``learn_many`` on the samples already in memory (the estimator's own rate: the reference),
* ``online-backlash estimate FILE --ratio 30`` through ``main()`` (read + validate + estimate),
  warm (the reader's and CLI's modules imported and numba's compiled estimator loaded before
  the timing, as for the reference; the reader's library, asammdf or pyarrow, is imported on
  first use, inside the timing), cold (all of that inside the timing) and as in a process that
  has estimated before (the reader's library imported, the consumer side's compiled loops and
  scipy import loaded by a short fit before the timing); ``estimate`` reads
  the file in a reader thread one block ahead while the estimator (compiled ``nogil``) learns,
* the same fit on one thread (``fit_recursive(..., ahead=0)``: reading and estimating in turn),
* the reader alone (``ParquetLog``/``MdfLog.iter_chunks()``; its compiled checks loaded from numba's
  cache before the timing, by reading its first chunk),
* the per-block checks alone (``replay/screen.screen_block`` and the gap rule) on the samples in
  memory, as contiguous columns (Parquet) and as views of interleaved records (MDF),
* the library's own bulk read of the whole file (``pyarrow.parquet.read_table``,
  ``asammdf.MDF.get``), which holds everything in memory.

Rates use the time of the call (imports excluded; they are printed separately: for the
reference they include reading the file and numba's compilation); peak RSS is the process's
``VmHWM`` (for the reference, with the whole recording in memory). Targets: ``estimate`` at >= 80 % of ``learn_many``'s
rate, peak RSS under 300 MB.

    python bench/measurement_files.py [--samples 10000000] [--dir /tmp] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

CHILD = """
import json, time
t_import = time.perf_counter()
{imports}
t = time.perf_counter()
{body}
seconds = time.perf_counter() - t
hwm = [line.split()[1] for line in open("/proc/self/status") if line.startswith("VmHWM:")][0]
print(json.dumps({{"seconds": seconds, "import_s": t - t_import, "max_rss_mb": int(hwm) / 1024, "out": out}}))
"""

#: numba's compiled estimator loaded (from its cache) once per process, outside the timing, as for the reference
WARM = (
    "from online_backlash import BacklashRLS\nfrom online_backlash.simulation.rig import simulate_rig\n"
    "_r = simulate_rig(20.0)\nBacklashRLS().learn_many(_r.motor_deg / 30, _r.load_deg)"
)
#: a process that has estimated before: the reader's library imported (asammdf through python-can, as the MDF
#: reader imports it; pyarrow), and the consumer side's compiled loops and its scipy import loaded by a fit of
#: 20 s of simulated samples (the estimator, the data clock, the play's scatter, the dwells); the reader's own
#: compiled checks still load inside the timing (on the reader thread)
STEADY = (
    "import importlib\nfor _m in {{'mdf': ['can', 'asammdf'], 'parquet': ['pyarrow.parquet']}}['{kind}']:\n"
    "    importlib.import_module(_m)\n"
    "from online_backlash.log_fit import fit_recursive\n"
    "from online_backlash.simulation.rig import simulate_rig\n"
    "fit_recursive([simulate_rig(20.0).to_chunk()], 30.0, ahead=1)"
)
ESTIMATE = (
    "import io, contextlib\nfrom online_backlash.cli import main, build_parser\n"
    "import online_backlash.replay.{kind}, online_backlash.log_fit\n" + WARM,
    "buf = io.StringIO()\nwith contextlib.redirect_stdout(buf):\n"
    "    main(['estimate', {path!r}, '--ratio', '30', '--json'{extra}])\n"
    "out = round(json.loads(buf.getvalue())['backlash_deg'], 5)",
)
COLD = "import io, contextlib\nfrom online_backlash.cli import main"
ESTIMATE_STEADY = (ESTIMATE[0] + "\n" + STEADY, ESTIMATE[1])
LEARN_MANY = (
    "import numpy as np, pyarrow.parquet as pq\nfrom online_backlash import BacklashRLS\n"
    "table = pq.read_table({path!r})\nu = table.column('motor').to_numpy() / 30.0\n"
    "y = table.column('load').to_numpy()\n"
    "BacklashRLS().learn_many(u[:20000], y[:20000])  # numba's compilation (or cache load), outside the timing",
    "est = BacklashRLS()\nfor i in range(0, u.size, 262144):\n    est.learn_many(u[i:i + 262144], y[i:i + 262144])\n"
    "out = round(est.backlash_, 5)",
)
#: the reader's compiled checks loaded (numba's cache) outside the timing, as they are in ``estimate``: its first
#: chunk read
FIRST_CHUNK = "with {reader} as _log:\n    next(iter(_log.iter_chunks()))"
#: the per-block checks of every column reader, on the samples in memory: one compiled pass over each block
#: (finiteness, angle limit, time order, repeats; the samples copied out where needed) and the gap rule
CHECKS = (
    "import numpy as np, pyarrow.parquet as pq\nfrom online_backlash.replay.block_checks import screen_block\n"
    "from online_backlash.codecs.gaps import GapDetector\n"
    "table = pq.read_table({path!r})\ncolumns = [table.column(c).to_numpy() for c in ('time', 'motor', 'load')]\n"
    "def check(columns, rows=65536):\n"
    "    gaps, last, n = GapDetector(), -np.inf, 0\n"
    "    for i in range(0, columns[0].size, rows):\n"
    "        block = [c[i:i + rows] for c in columns]\n"
    "        out = None if block[1].flags.c_contiguous else np.empty((4, block[0].size))\n"
    "        found = screen_block(block, (1e15, 1e15), last, (1.0, 1.0), out)\n"
    "        last = found.last_time\n"
    "        n += gaps.check_times(block[0] if out is None else out[0])[0].size\n"
    "    return n\n"
    "check([c[:100000] for c in columns])",
    "out = check(columns)",
)
#: the columns as views of interleaved records (time, motor, load: 24 bytes a record), as MDF channel groups lie
RECORDS = "\ncolumns = list(np.column_stack(columns).T)\ncheck([c[:100000] for c in columns])"
CASES = {
    "`BacklashRLS.learn_many`, samples in memory (reference)": ("parquet", LEARN_MANY, ""),
    "`estimate` of the Parquet file": ("parquet", ESTIMATE, ""),
    "`estimate` of the Parquet file, cold (lazy imports and numba's cache load timed too)": (
        "parquet",
        (COLD, ESTIMATE[1]),
        "",
    ),
    "`estimate` of the Parquet file, pyarrow imported and the consumer's compiled loops loaded": (
        "parquet",
        ESTIMATE_STEADY,
        "",
    ),
    "`fit_recursive` of the Parquet file on one thread (no read-ahead)": (
        "parquet",
        (
            "from online_backlash.replay.parquet import ParquetLog\nfrom online_backlash.log_fit import fit_recursive\n"
            + WARM,
            "with ParquetLog({path!r}) as log:\n"
            "    out = round(fit_recursive(log.iter_chunks(), 30.0, ahead=0)[0].backlash_deg, 5)",
        ),
        "",
    ),
    "`ParquetLog.iter_chunks()` alone": (
        "parquet",
        (
            "from online_backlash.replay.parquet import ParquetLog\n"
            + FIRST_CHUNK.format(reader="ParquetLog({path!r})"),
            "with ParquetLog({path!r}) as log:\n    out = sum(len(c) for c in log.iter_chunks())",
        ),
        "",
    ),
    "the block checks alone (`screen_block` + the gap rule, blocks of 65,536 rows), contiguous columns": (
        "parquet",
        CHECKS,
        "",
    ),
    "the block checks alone, columns strided in records (as MDF), samples copied out": (
        "parquet",
        (CHECKS[0] + RECORDS, CHECKS[1]),
        "",
    ),
    "`pyarrow.parquet.read_table` (whole file)": (
        "parquet",
        ("import pyarrow.parquet as pq", "out = pq.read_table({path!r}).num_rows"),
        "",
    ),
    "`estimate` of the MDF4 file": ("mf4", ESTIMATE, ", '--columns', 'motor=Motor,load=Load'"),
    "`estimate` of the MDF4 file, cold": ("mf4", (COLD, ESTIMATE[1]), ", '--columns', 'motor=Motor,load=Load'"),
    "`estimate` of the MDF4 file, asammdf imported and the consumer's compiled loops loaded": (
        "mf4",
        ESTIMATE_STEADY,
        ", '--columns', 'motor=Motor,load=Load'",
    ),
    "`fit_recursive` of the MDF4 file on one thread (no read-ahead)": (
        "mf4",
        (
            "from online_backlash.replay.mdf import MdfLog\nfrom online_backlash.log_fit import fit_recursive\n" + WARM,
            "with MdfLog({path!r}, columns={{'motor': 'Motor', 'load': 'Load'}}) as log:\n"
            "    out = round(fit_recursive(log.iter_chunks(), 30.0, ahead=0)[0].backlash_deg, 5)",
        ),
        "",
    ),
    "`MdfLog.iter_chunks()` alone": (
        "mf4",
        (
            "from online_backlash.replay.mdf import MdfLog\n"
            + FIRST_CHUNK.format(reader="MdfLog({path!r}, columns={{'motor': 'Motor', 'load': 'Load'}})"),
            "with MdfLog({path!r}, columns={{'motor': 'Motor', 'load': 'Load'}}) as log:\n"
            "    out = sum(len(c) for c in log.iter_chunks())",
        ),
        "",
    ),
    "`asammdf.MDF.get` of both channels (whole file)": (
        "mf4",
        (
            "from asammdf import MDF",
            "mdf = MDF({path!r})\nout = len(mdf.get('Motor').samples) + 0 * len(mdf.get('Load').samples)\nmdf.close()",
        ),
        "",
    ),
}


def write_files(samples: int, folder: str) -> dict[str, str]:
    """The rig recording as Parquet and MDF4 in ``folder`` (kept between runs)."""
    paths = {
        "parquet": os.path.join(folder, f"online-backlash-rig-{samples}.parquet"),
        "mf4": os.path.join(folder, f"online-backlash-rig-{samples}.mf4"),
    }
    if all(os.path.exists(p) for p in paths.values()):
        return paths
    import pyarrow as pa
    import pyarrow.parquet as pq
    from asammdf import MDF, Signal

    from online_backlash.simulation.rig import simulate_rig

    t0 = time.perf_counter()
    rec = simulate_rig(duration_s=samples / 1000.0, play_deg=0.5, seed=3)
    pq.write_table(
        pa.table({"time": rec.time_s, "motor": rec.motor_deg, "load": rec.load_deg}),
        paths["parquet"],
        row_group_size=1_000_000,
    )
    mdf = MDF(version="4.10")
    mdf.append(
        [
            Signal(rec.motor_deg, rec.time_s, name="Motor", unit="deg"),
            Signal(rec.load_deg, rec.time_s, name="Load", unit="deg"),
        ]
    )
    mdf.save(paths["mf4"], overwrite=True)
    mdf.close()
    sizes = ", ".join(f"{os.path.getsize(p) / 2**20:.0f} MiB" for p in paths.values())
    print(f"wrote {', '.join(paths.values())} ({sizes}) in {time.perf_counter() - t0:.0f} s")
    return paths


def run_child(imports: str, body: str) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", CHILD.format(imports=imports, body=body)], capture_output=True, text=True
    )
    if done.returncode:
        raise SystemExit(f"a benchmark case failed (exit {done.returncode}):\n{body}\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=10_000_000)
    ap.add_argument("--dir", default="/tmp", help="where to keep the generated files")
    ap.add_argument(
        "--repeat",
        type=int,
        default=3,
        help="runs of each case, interleaved; the fastest is reported, with the highest peak RSS",
    )
    args = ap.parse_args()
    paths = write_files(args.samples, args.dir)
    results: dict[str, dict] = {}
    for _ in range(args.repeat):
        for name, (kind, (imports, body), extra) in CASES.items():
            res = run_child(
                imports.format(path=paths[kind], kind="parquet" if kind == "parquet" else "mdf"),
                body.format(path=paths[kind], extra=extra),
            )
            best = results.setdefault(name, res)
            if res["seconds"] < best["seconds"]:
                results[name] = {**res, "max_rss_mb": max(res["max_rss_mb"], best["max_rss_mb"])}
            else:
                best["max_rss_mb"] = max(res["max_rss_mb"], best["max_rss_mb"])
    reference = args.samples / results["`BacklashRLS.learn_many`, samples in memory (reference)"]["seconds"]
    import asammdf
    import pyarrow

    versions = f"python {platform.python_version()}, pyarrow {pyarrow.__version__}, asammdf {asammdf.__version__}"
    print(f"{versions}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the end")
    print("| what | seconds | samples/s | vs learn_many | peak RSS (MB) | imports (s) | result |")
    print("|---|---:|---:|---:|---:|---:|---|")
    for name, res in results.items():
        rate = args.samples / res["seconds"]
        print(
            f"| {name} | {res['seconds']:.2f} | {rate:,.0f} | {rate / reference:.0%} | {res['max_rss_mb']:.0f} | "
            f"{res['import_s']:.1f} | {res['out']} |"
        )


if __name__ == "__main__":
    main()
