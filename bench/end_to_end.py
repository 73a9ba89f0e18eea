"""``online-backlash estimate`` of a measurement file end to end, start-up subtracted, beside ``learn_many``.

Issue 31's measure. The simulated 30:1 rig (1 kHz, play 0.5 deg) is written once in every format
(``--samples`` samples, and a 2,000-sample file of the same rig reversing every 0.2-0.4 s, so that it
starts): MDF4 (asammdf, one float64 channel group), Arrow IPC (uncompressed), Parquet uncompressed, LZ4
and snappy (pyarrow's default; row groups of 1,000,000 rows) and CSV. Then, ``--rounds`` times, in the
same order every round (one process at a time, so the compared things meet the same machine):

* ``estimate BIG --json`` and ``estimate SMALL --json`` of each format, each a fresh process
  (``online-backlash``'s ``main``): wall time, CPU time (user + system, all threads, from ``wait4``) and
  peak RSS of the process;
* the reference, in a fresh process: ``BacklashRLS().learn_many(u, y)`` on the samples of the big file
  in memory (read before the timing; numba's compiled loop loaded on 20,000 other samples first), and the
  same with the estimator as ``estimate`` sets it up (``log_fit.KINEMATIC``: ``full_engagement``, issue 27,
  judges every sample's engagement in a second compiled pass);
* the library's own decode of the snappy Parquet file alone (``ParquetFile.iter_batches`` of the three
  columns, as the reader calls it, the values taken without a copy), in a fresh process, timed after
  the import;
* the reader's side alone, in a fresh process: what ``estimate``'s reader thread does (``open_log(BIG)``'s
  blocks, each referred to the load side and checked, ``Pipeline._refer``), timed after the imports and a
  pass over the small file (numba's cache loads), for each format: its CPU beside the decode's and
  ``estimate``'s splits the CPU beyond into the reader's part and the estimator's.

Memory, per phase: the resident size once the CLI's modules are imported (``build_parser``, before the
command runs), the peak of the small file (beyond that: the reader's libraries, numba's compiled-code
machinery, the estimator's kernels loaded from the cache) and the peak of the big one (beyond that: the
blocks in flight and what grows with the samples).

``estimate``'s rate is ``(samples BIG - samples SMALL) / (time BIG - time SMALL)``: the start-up
(interpreter, imports, numba's cache loads, the file's opening) is paid by both and cancels. The table
gives the median of the rounds with the range beside it, against ``learn_many``'s median rate (the
issue's aim: >= 80 % for MDF4, Arrow IPC and uncompressed or LZ4 Parquet), the CPU seconds over the
start-up's, and for snappy Parquet the CPU beyond (decode alone + ``learn_many``) (aim: <= 10 %).

    python bench/end_to_end.py [--samples 10000000] [--dir /tmp/online-backlash-e2e] [--rounds 5] [--only mf4,arrow]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

#: format -> (file name suffix, extra ``estimate`` options)
FORMATS = {
    "mf4": (".mf4", ["--columns", "motor=Motor,load=Load"]),
    "arrow": (".arrow", []),
    "parquet-none": ("-none.parquet", []),
    "parquet-lz4": ("-lz4.parquet", []),
    "parquet-snappy": ("-snappy.parquet", []),
    "csv": (".csv", []),
}
SMALL_SAMPLES = 2000
#: put before every child's code: its peak RSS (``VmHWM``, kB) on the last line of its stderr at exit (``wait4``'s
#: ``ru_maxrss`` would carry this process's peak across fork and exec)
PEAK = (
    "import atexit, os\natexit.register(lambda: os.write(2, ('\\nVmHWM ' + [line.split()[1] for line in "
    "open('/proc/self/status') if line.startswith('VmHWM:')][0] + '\\n').encode()))\n"
)

ESTIMATE = """
import sys
from online_backlash.cli import build_parser, main
build_parser()  # every subcommand's module imported, as main does: the resident size before the command runs
os.write(2, ('\\nVmRSS-imports ' + [line.split()[1] for line in open('/proc/self/status')
             if line.startswith('VmRSS:')][0] + '\\n').encode())
sys.exit(main(sys.argv[1:]))
"""
REFERENCE = """
import json, sys, time
import numpy as np, pyarrow.parquet as pq
from online_backlash import BacklashRLS
from online_backlash.log_fit import KINEMATIC
options = KINEMATIC if sys.argv[2] == "estimate's" else {}
table = pq.read_table(sys.argv[1])
u = np.ascontiguousarray(table.column("motor").to_numpy()) / 30.0
y = np.ascontiguousarray(table.column("load").to_numpy())
BacklashRLS(**options).learn_many(u[-20000:], y[-20000:])  # numba's cache load, outside the timing
wall, cpu = time.perf_counter(), time.process_time()
est = BacklashRLS(**options)
est.learn_many(u, y)
print(json.dumps({"wall": time.perf_counter() - wall, "cpu": time.process_time() - cpu, "play": est.backlash_}))
"""
DECODE = """
import json, sys, time
import numpy as np, pyarrow as pa, pyarrow.parquet as pq
wall, cpu = time.perf_counter(), time.process_time()
source = pa.OSFile(sys.argv[1], "rb")
rows = 0
for batch in pq.ParquetFile(source, pre_buffer=False, buffer_size=1 << 20).iter_batches(
        batch_size=65536, columns=["time", "motor", "load"], use_threads=True):
    values = [np.frombuffer(c.buffers()[1], dtype=np.float64, count=len(c), offset=c.offset * 8) for c in batch.columns]
    rows += values[0].size
print(json.dumps({"wall": time.perf_counter() - wall, "cpu": time.process_time() - cpu, "rows": rows}))
"""

READ = """
import json, sys, time
from online_backlash import BacklashRLS
from online_backlash.pipeline import Pipeline
from online_backlash.replay import open_log
options = json.loads(sys.argv[3])
def read(path):
    refer = Pipeline(BacklashRLS(), 30.0, 1.0, rows=False)._refer  # as the reader thread of estimate: checked, referred
    with open_log(path, **options) as log:
        return sum(len(referred[0]) for referred in map(refer, log.iter_chunks()) if referred is not None)
read(sys.argv[2])  # imports and numba's cache loads, outside the timing
wall, cpu = time.perf_counter(), time.process_time()
rows = read(sys.argv[1])
print(json.dumps({"wall": time.perf_counter() - wall, "cpu": time.process_time() - cpu, "rows": rows}))
"""
#: ``open_log`` options of each format's files (as ``FORMATS``' ``estimate`` options say)
READ_OPTIONS = {"mf4": {"columns": {"motor": "Motor", "load": "Load"}}}


def write_files(folder: Path, samples: int) -> dict[str, tuple[Path, Path]]:
    """format -> (big file, 2,000-sample file), written once into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = {
        kind: (folder / f"rig-{samples}{suffix}", folder / f"rig-{SMALL_SAMPLES}{suffix}")
        for kind, (suffix, _) in FORMATS.items()
    }
    if all(p.exists() for pair in paths.values() for p in pair):
        return paths
    from same_results import bench_rig, write_rig_formats  # (this folder: the same files as the byte-identity check's)

    records = (bench_rig(samples), bench_rig(SMALL_SAMPLES, quick=True))
    for which, rec in enumerate(records):
        parquet = {compression: paths[f"parquet-{compression}"][which] for compression in ("none", "lz4", "snappy")}
        write_rig_formats(rec, parquet, paths["arrow"][which], paths["mf4"][which], paths["csv"][which])
    return paths


def run(code: str, *argv: str) -> dict:
    """``python -c code argv...``: its wall time, CPU time (user + system, all threads, from ``wait4``: the
    process's own, not the children's totals), peak RSS (MB) and stdout."""
    wall = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", PEAK + code, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    out = proc.stdout.read()  # type: ignore[union-attr]
    err = proc.stderr.read()  # type: ignore[union-attr]
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - wall
    proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait for it again
    if proc.returncode:
        raise SystemExit(f"failed ({proc.returncode}): {argv}\n{err.decode()[-2000:]}")
    peak_kb = int(err.decode().rsplit("VmHWM ", 1)[1])
    imports = err.decode().rsplit("VmRSS-imports ", 1)[1:]
    return {
        "wall": wall,
        "cpu": usage.ru_utime + usage.ru_stime,
        "rss_mb": peak_kb / 1024,
        "imports_mb": int(imports[0].split()[0]) / 1024 if imports else math.nan,
        "out": out.decode(),
    }


def spread(values: list[float], fmt: str = "{:.2f}") -> str:
    """The median with the range of ``values``."""
    return f"{fmt.format(statistics.median(values))} ({fmt.format(min(values))}-{fmt.format(max(values))})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=10_000_000)
    ap.add_argument("--dir", type=Path, default=Path("/tmp/online-backlash-e2e"), help="where the files are kept")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--only", default=",".join(FORMATS), help="formats, comma-separated: " + ", ".join(FORMATS))
    args = ap.parse_args()
    paths = write_files(args.dir, args.samples)
    kinds = [k for k in args.only.split(",") if k]
    runs: dict[str, list[dict]] = {}
    load = [os.getloadavg()[0]]
    for _ in range(args.rounds):
        for setup in ("default", "estimate's"):
            runs.setdefault(f"reference {setup}", []).append(run(REFERENCE, str(paths["parquet-none"][0]), setup))
        runs.setdefault("decode", []).append(run(DECODE, str(paths["parquet-snappy"][0])))
        for kind in kinds:
            options = json.dumps(READ_OPTIONS.get(kind, {}))
            runs.setdefault(f"read {kind}", []).append(run(READ, str(paths[kind][0]), str(paths[kind][1]), options))
            options = ["--ratio", "30", *FORMATS[kind][1], "--json"]
            for size, path in zip(("big", "small"), paths[kind]):
                runs.setdefault(f"{kind} {size}", []).append(run(ESTIMATE, "estimate", str(path), *options))
        load.append(os.getloadavg()[0])
    inner = {k: [json.loads(r["out"]) for r in runs[k]] for k in runs if not k.endswith(("big", "small"))}
    ref_rate = [args.samples / r["wall"] for r in inner["reference default"]]
    ref_cpu = [r["cpu"] for r in inner["reference default"]]
    setup_rate = [args.samples / r["wall"] for r in inner["reference estimate's"]]
    setup_cpu = [r["cpu"] for r in inner["reference estimate's"]]
    decode_cpu = [r["cpu"] for r in inner["decode"]]
    extra = args.samples - SMALL_SAMPLES
    print(
        f"{args.samples:,} samples; {os.cpu_count()} cores ({platform.machine()}), Python {platform.python_version()}; "
        f"{args.rounds} rounds; load average {min(load):.1f}-{max(load):.1f} (1 min, at each round's start and the end)"
    )
    print(
        f"`learn_many` on the samples in memory: {spread([r / 1e6 for r in ref_rate], '{:.1f}')} M samples/s "
        f"(wall; CPU {spread(ref_cpu, '{:.3f}')} s); as `estimate` sets it up (full_engagement) "
        f"{spread([r / 1e6 for r in setup_rate], '{:.1f}')} M samples/s (CPU "
        f"{spread(setup_cpu, '{:.3f}')} s); "
        f"snappy decode alone {spread(decode_cpu, '{:.3f}')} CPU-s\n"
    )
    print(
        "| file | estimate BIG: wall s | SMALL: wall s | BIG - SMALL: wall s | M samples/s | vs learn_many "
        "| vs learn_many as estimate sets it up | CPU s over SMALL's | vs learn_many's CPU | reader alone: CPU s "
        "| RSS after imports / peak SMALL / peak BIG (its lowest round), MB |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for kind in kinds:
        big, small = runs[f"{kind} big"], runs[f"{kind} small"]
        wall = [b["wall"] - s["wall"] for b, s in zip(big, small)]
        cpu = [b["cpu"] - s["cpu"] for b, s in zip(big, small)]
        share = [extra / w / r for w, r in zip(wall, ref_rate)]
        print(
            f"| {kind} | {spread([b['wall'] for b in big])} | {spread([s['wall'] for s in small])} | {spread(wall)} "
            f"| {spread([extra / w / 1e6 for w in wall], '{:.1f}')} | {spread([100 * s for s in share], '{:.0f}')} % "
            f"| {spread([100 * extra / w / r for w, r in zip(wall, setup_rate)], '{:.0f}')} % "
            f"| {spread(cpu)} | {spread([100 * c / r for c, r in zip(cpu, ref_cpu)], '{:.0f}')} % "
            f"| {spread([r['cpu'] for r in inner[f'read {kind}']], '{:.3f}')} "
            f"| {max(b['imports_mb'] for b in big):.0f} / {max(s['rss_mb'] for s in small):.0f} "
            f"/ {max(b['rss_mb'] for b in big):.0f} ({min(b['rss_mb'] for b in big):.0f}) |"
        )
    if "parquet-snappy" in kinds:
        cpu = [b["cpu"] - s["cpu"] for b, s in zip(runs["parquet-snappy big"], runs["parquet-snappy small"])]
        beyond = [100 * (c / (d + r) - 1) for c, d, r in zip(cpu, decode_cpu, ref_cpu)]
        reader = [r["cpu"] - d for r, d in zip(inner["read parquet-snappy"], decode_cpu)]
        rest = [c - r["cpu"] - f for c, r, f in zip(cpu, inner["read parquet-snappy"], ref_cpu)]
        print(
            f"\nsnappy Parquet: CPU beyond (decode alone + learn_many): {spread(beyond, '{:+.0f}')} %; of it the "
            f"reader's side beyond the decode {spread(reader, '{:.3f}')} CPU-s, the estimator's side beyond "
            f"learn_many (estimate - reader alone - learn_many) {spread(rest, '{:.3f}')} CPU-s"
        )


if __name__ == "__main__":
    main()
