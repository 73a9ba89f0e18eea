"""How long ``online-backlash diagnose`` takes beside ``estimate --method batch`` on the same log.

For every length (default 2, 10 and 60 minutes), a two-mass rig log (30:1, 1 kHz, 14-bit motor,
17-bit load, measured torque, continuous rotation with reversals: the compliance case of
``bench/closing_loop.py``) is written as CSV; then ``online-backlash estimate --method batch
--json`` and ``online-backlash diagnose --json`` run on it one after the other, in this process
through ``main(argv)`` (CSV reading included in both), wall clock and CPU time of this process.
Both commands are run once untimed first (the batch fit on the same log, ``diagnose`` once on a
30 s log), so that neither pays its imports or the loading of its compiled functions.
Prints a markdown table with the ratio diagnose / batch (the issue's figure: within 4x), and the
1-minute load average after each row (on a shared machine CPU seconds are the steadier figure).

Run: ``python bench/diagnose_speed.py`` (about 10 minutes on 2 shared cores);
``--minutes 2,10`` shrinks it. The CSVs are cached in ``--dir``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import platform
import time
from pathlib import Path

from online_backlash.cli import main as cli
from online_backlash.two_mass_rig import simulate_two_mass

COLUMNS = ["--columns", "time=time,motor=motor,load=load,torque=torque"]
#: length of the log of the warm-up ``diagnose`` run (imports and compiled caches, not timed), minutes
WARM_MINUTES = 0.5


def write_log(minutes: float, directory: Path) -> Path:
    path = directory / f"two_mass_{minutes:g}min.csv"
    if not path.exists():
        rec = simulate_two_mass(duration_s=60.0 * minutes, motion="rig", coulomb_nm=0.05, seed=0)
        rec.write_csv(path)
    return path


def timed(argv: list[str]) -> tuple[float, float, str]:
    """Wall and CPU seconds of one CLI run, and its stdout."""
    out = io.StringIO()
    w0, c0 = time.perf_counter(), time.process_time()
    with contextlib.redirect_stdout(out):
        code = cli(argv)
    w1, c1 = time.perf_counter(), time.process_time()
    if code:
        raise SystemExit(f"{argv[0]} exited with {code}")
    return w1 - w0, c1 - c0, out.getvalue()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", default="2,10,60", help="comma-separated log lengths, minutes")
    parser.add_argument("--dir", default="/tmp/online_backlash_bench", help="where the CSV logs are cached")
    args = parser.parse_args()
    directory = Path(args.dir)
    directory.mkdir(parents=True, exist_ok=True)
    load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, load average {load}\n")
    print("| log | samples | batch wall, s | batch CPU, s | diagnose wall, s | diagnose CPU, s | ratio (wall) | ratio (CPU) | terms found | load after |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    warm = False
    for minutes in (float(m) for m in args.minutes.split(",")):
        path = write_log(minutes, directory)
        common = [str(path), "--ratio", "30", *COLUMNS]
        with contextlib.redirect_stdout(io.StringIO()):  # compile caches and imports outside the timing
            cli(["estimate", *common, "--method", "batch", "--json"])
            if not warm:  # diagnose's own imports (scipy.optimize, scipy.interpolate) and compiled caches
                cli(["diagnose", str(write_log(WARM_MINUTES, directory)), "--ratio", "30", *COLUMNS, "--json"])
                warm = True
        bw, bc, _ = timed(["estimate", *common, "--method", "batch", "--json"])
        dw, dc, text = timed(["diagnose", *common, "--json"])
        d = json.loads(text)
        found = [e["name"] for e in d["effects"]] + [f"({e['name']})" for e in d["unexplained"]]
        print(
            f"| {minutes:g} min | {d['samples']} | {bw:.2f} | {bc:.2f} | {dw:.2f} | {dc:.2f} | {dw / bw:.2f} | {dc / bc:.2f} | {', '.join(found) or '-'} "
            f"| {os.getloadavg()[0]:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
