"""The Parquet reader's options alone: wall, CPU and peak RSS of reading three float64 columns.

Reads the 10-million-row rig file of ``bench/measurement_files.py`` (pyarrow with its defaults:
snappy, dictionary pages falling back to plain, row groups of 1,000,000 rows; written there if
absent) in each of the ways pyarrow offers, beside snappy's decompression of the same values
alone and an uncompressed copy of the file (what the decode costs without snappy), every case in a fresh interpreter
(peak RSS is the process's ``VmHWM``; ``RSS over base`` subtracts the ``VmRSS`` after the imports), the cases
interleaved ``--repeat`` times, the lowest CPU time reported with the highest peak RSS. CPU is ``time.process_time()``
(all threads of the process): on a loaded machine it is the steadier figure, and on two cores it is what bounds a reader
thread running beside the estimator.

    python bench/parquet_read.py [--samples 10000000] [--dir /tmp] [--repeat 3] [--only WORD]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = """
import json, os, time
import numpy as np
import pyarrow as pa, pyarrow.parquet as pq
PATH, PLAIN, NAMES = {path!r}, {plain!r}, ["time", "motor", "load"]
{imports}
base = [line.split()[1] for line in open("/proc/self/status") if line.startswith("VmRSS:")][0]
wall, cpu = time.perf_counter(), time.process_time()
{body}
wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
hwm = [line.split()[1] for line in open("/proc/self/status") if line.startswith("VmHWM:")][0]
print(json.dumps({{"wall": wall, "cpu": cpu, "hwm_mb": int(hwm) / 1024, "base_mb": int(base) / 1024, "rows": rows}}))
"""

#: a batch's three columns as numpy arrays without copies (what the reader hands on)
VALUES = "[np.frombuffer(c.buffers()[1], dtype=np.float64, count=len(c), offset=c.offset * 8) for c in {batch}.columns]"


def iter_batches(
    batch_rows: int,
    threads: bool,
    source: str = "pa.OSFile(PATH, 'rb')",
    pre_buffer: bool = False,
    buffer_size: int = 1 << 20,
) -> str:
    return (
        f"source = {source}\nfile = pq.ParquetFile(source, pre_buffer={pre_buffer}, buffer_size={buffer_size})\n"
        "rows = 0\n"
        f"for batch in file.iter_batches(batch_size={batch_rows}, columns=NAMES, use_threads={threads}):\n"
        f"    rows += len({VALUES.format(batch='batch')}[0])\nsource.close()"
    )


def row_groups(
    threads: bool, source: str = "pa.OSFile(PATH, 'rb')", pre_buffer: bool = False, buffer_size: int = 0
) -> str:
    return (
        f"source = {source}\nfile = pq.ParquetFile(source, pre_buffer={pre_buffer}, buffer_size={buffer_size})\n"
        "rows = 0\n"
        f"for i in range(file.num_row_groups):\n"
        f"    table = file.read_row_group(i, columns=NAMES, use_threads={threads})\n"
        f"    rows += sum(len(c) for c in table.column(0).chunks)\n    del table\nsource.close()"
    )


def scanner(batch_rows: int, threads: bool, batch_readahead: int, fragment_readahead: int, pre_buffer: bool) -> str:
    return (
        "import pyarrow.dataset as ds\n"
        "fmt = ds.ParquetFileFormat(default_fragment_scan_options="
        f"ds.ParquetFragmentScanOptions(pre_buffer={pre_buffer}))\n"
        "data = ds.dataset(PATH, format=fmt)\nrows = 0\n"
        f"for batch in data.to_batches(columns=NAMES, batch_size={batch_rows}, use_threads={threads}, "
        f"batch_readahead={batch_readahead}, fragment_readahead={fragment_readahead}):\n"
        "    rows += batch.num_rows"
    )


#: the snappy pages of the three columns (about 1 MiB each, as pyarrow writes them), compressed before the timing
SNAPPY = (
    "codec = pa.Codec('snappy')\ncolumns = pq.read_table(PATH, columns=NAMES)\n"
    "pages = [(codec.compress(part), part.nbytes) for name in NAMES for c in [columns.column(name).to_numpy()]\n"
    "         for part in (c[i:i + 131072] for i in range(0, c.size, 131072))]\ndel columns"
)
MMAP = "pa.memory_map(PATH, 'r')"
CASES: dict[str, tuple[str, str, dict[str, str]]] = {
    "`iter_batches(65536)`, use_threads=False, OSFile, buffer 1 MiB (the reader before)": (
        "",
        iter_batches(65536, False),
        {},
    ),
    "`iter_batches(65536)`, use_threads=True (the reader now)": ("", iter_batches(65536, True), {}),
    "`iter_batches(65536)`, unbuffered (buffer_size=0)": ("", iter_batches(65536, False, buffer_size=0), {}),
    "`iter_batches(65536)`, pre_buffer=True": ("", iter_batches(65536, False, pre_buffer=True, buffer_size=0), {}),
    "`iter_batches(65536)`, memory_map": ("", iter_batches(65536, False, source=MMAP, buffer_size=0), {}),
    "`iter_batches(262144)`": ("", iter_batches(262144, False), {}),
    "`iter_batches(1048576)`": ("", iter_batches(1 << 20, False), {}),
    "`iter_batches(65536)`, system allocator": (
        "",
        iter_batches(65536, False),
        {"ARROW_DEFAULT_MEMORY_POOL": "system"},
    ),
    "`iter_batches(65536)`, jemalloc": ("", iter_batches(65536, False), {"ARROW_DEFAULT_MEMORY_POOL": "jemalloc"}),
    "`read_row_group(i)`, OSFile unbuffered": ("", row_groups(False), {}),
    "`read_row_group(i)`, use_threads=True": ("", row_groups(True), {}),
    "`read_row_group(i)`, pre_buffer=True": ("", row_groups(False, pre_buffer=True), {}),
    "`read_row_group(i)`, memory_map": ("", row_groups(False, source=MMAP), {}),
    "`read_row_group(i)`, memory_map, system allocator": (
        "",
        row_groups(False, source=MMAP),
        {"ARROW_DEFAULT_MEMORY_POOL": "system"},
    ),
    "`read_row_group(i)`, memory_map, use_threads=True": ("", row_groups(True, source=MMAP), {}),
    "dataset scanner, batches of 65536, no threads, readahead 1/1": ("", scanner(65536, False, 1, 1, False), {}),
    "dataset scanner, batches of 65536, threads, default readahead (16/4), pre_buffer": (
        "",
        scanner(65536, True, 16, 4, True),
        {},
    ),
    "snappy's decompression alone, the same values as 1 MiB pages (`pa.Codec('snappy').decompress`)": (
        SNAPPY,
        "size = 0\nfor page, n in pages:\n    size += len(codec.decompress(page, decompressed_size=n))\n"
        "rows = size // 24",
        {},
    ),
    "the same rows written uncompressed (`compression='none'`), `iter_batches(65536)`": (
        "",
        iter_batches(65536, False, source="pa.OSFile(PLAIN, 'rb')"),
        {},
    ),
    "`read_table` (whole file), use_threads=False": (
        "",
        "rows = pq.read_table(PATH, columns=NAMES, use_threads=False).num_rows",
        {},
    ),
    "`read_table` (whole file), defaults": ("", "rows = pq.read_table(PATH, columns=NAMES).num_rows", {}),
    "`ParquetLog.iter_chunks()` (the reader, with its checks)": (
        "from online_backlash.replay.parquet import ParquetLog\nwith ParquetLog({path!r}) as _log:\n"
        "    next(iter(_log.iter_chunks()))",
        "with ParquetLog(PATH) as log:\n    rows = sum(len(c) for c in log.iter_chunks())",
        {},
    ),
}


def ensure_files(samples: int, folder: str) -> tuple[str, str]:
    """The rig file of ``bench/measurement_files.py`` (written by it if absent) and an uncompressed copy."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from measurement_files import write_files

    path = write_files(samples, folder)["parquet"]
    plain = path.replace(".parquet", "-uncompressed.parquet")
    if not os.path.exists(plain):
        import pyarrow.parquet as pq

        pq.write_table(pq.read_table(path), plain, row_group_size=1_000_000, compression="none")
    return path, plain


def run(imports: str, body: str, paths: tuple[str, str], env: dict[str, str]) -> dict:
    code = CHILD.format(imports=imports.format(path=paths[0]), path=paths[0], plain=paths[1], body=body)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env={**os.environ, **env})
    if done.returncode:
        raise SystemExit(f"a case failed (exit {done.returncode}):\n{body}\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=10_000_000)
    ap.add_argument("--dir", default="/tmp", help="where the generated files are kept")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each case, interleaved")
    ap.add_argument("--only", default="", help="run only the cases whose name contains this")
    args = ap.parse_args()
    paths = ensure_files(args.samples, args.dir)
    cases = {name: case for name, case in CASES.items() if args.only in name}
    best: dict[str, dict] = {}
    for _ in range(args.repeat):
        for name, (imports, body, env) in cases.items():
            res = run(imports, body, paths, env)
            if res["rows"] != args.samples:
                raise SystemExit(f"{name}: read {res['rows']} rows, not {args.samples}")
            old = best.setdefault(name, res)
            hwm = max(old["hwm_mb"], res["hwm_mb"])
            if res["cpu"] < old["cpu"]:
                best[name] = res
            best[name]["hwm_mb"] = hwm
    print(
        f"{args.samples:,} rows, {len(cases)} cases x {args.repeat}, load average {os.getloadavg()[0]:.1f} at the end"
    )
    print("| option | wall, s | CPU, s | peak RSS (MB) | RSS over base (MB) |")
    print("|---|---:|---:|---:|---:|")
    for name, res in best.items():
        print(
            f"| {name} | {res['wall']:.2f} | {res['cpu']:.2f} | {res['hwm_mb']:.0f} | "
            f"{res['hwm_mb'] - res['base_mb']:.0f} |"
        )


if __name__ == "__main__":
    main()
