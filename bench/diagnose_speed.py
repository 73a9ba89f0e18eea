"""How long ``online-backlash diagnose`` takes beside ``estimate --method batch`` on the same log.

For every length (default 2, 10 and 60 minutes), a two-mass rig log (30:1, 1 kHz, 14-bit motor,
17-bit load, measured torque, continuous rotation with reversals: the compliance case of
``bench/closing_loop.py``) is written as CSV; then ``online-backlash estimate --method batch
--json`` and ``online-backlash diagnose --json`` are timed on it side by side, each in a process of
its own (a child of this script, ``--one``) that runs the command through ``main(argv)`` (CSV reading
included) once on a 30 s log untimed (imports, the loading of compiled functions), then twice on
the log, timed: wall clock and CPU time of that process. The first timed run meets memory the
process has not used at this size yet (what a fresh process pays, imports aside), the second meets
it warm; both commands are treated alike, and neither sees memory the other touched.

Prints a markdown table with the ratio diagnose / batch for the first and for the second runs (issue
31's figures: within 2x on the 10-minute log, 3x on the 2-minute one), and the 1-minute load average
after each row (on a shared machine CPU seconds are the steadier figure).

``--reference DIR`` times another tree beside this one in the same run: ``DIR`` holds a staged
package (``DIR/online_backlash``, first on the children's ``PYTHONPATH``), and every length is timed
``--rounds`` times, the two trees alternating (this tree first), each in processes of its own.

Run: ``python bench/diagnose_speed.py`` (about 2 minutes on 2 cores); ``--minutes 2,10`` shrinks
it. The CSVs are cached in ``--dir``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

from online_backlash.cli import main as cli
from online_backlash.simulation.two_mass_rig import simulate_two_mass

COLUMNS = ["--ratio", "30", "--columns", "time=time,motor=motor,load=load,torque=torque", "--json"]
#: length of the log of the warm-up run (imports and compiled caches, not timed), minutes
WARM_MINUTES = 0.5
#: timed runs of each command in its process
RUNS = 2


def write_log(minutes: float, directory: Path) -> Path:
    path = directory / f"two_mass_{minutes:g}min.csv"
    if not path.exists():
        rec = simulate_two_mass(duration_s=60.0 * minutes, motion="rig", coulomb_nm=0.05, seed=0)
        rec.write_csv(path)
    return path


def argv_of(command: str, path: Path) -> list[str]:
    return [command, str(path), *COLUMNS, *(["--method", "batch"] if command == "estimate" else [])]


def one(command: str, path: Path, warm: Path) -> None:
    """In the child: the command once on ``warm`` untimed, then :data:`RUNS` times on ``path``; prints
    JSON ``{"wall": [...], "cpu": [...], "stdout": last run's output}``."""
    with contextlib.redirect_stdout(io.StringIO()):
        cli(argv_of(command, warm))
    walls, cpus, text = [], [], ""
    for _ in range(RUNS):
        out = io.StringIO()
        w0, c0 = time.perf_counter(), time.process_time()
        with contextlib.redirect_stdout(out):
            code = cli(argv_of(command, path))
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
        if code:
            raise SystemExit(f"{command} exited with {code}")
        text = out.getvalue()
    print(json.dumps({"wall": walls, "cpu": cpus, "stdout": text}))


def timed(command: str, path: Path, warm: Path, package: str | None = None) -> dict:
    """:func:`one` in a child process (the same interpreter and environment; ``package``: a folder put first
    on its ``PYTHONPATH``, the tree it times)."""
    env = os.environ.copy()
    if package:
        env["PYTHONPATH"] = os.pathsep.join(p for p in (package, env.get("PYTHONPATH")) if p)
    done = subprocess.run(
        [sys.executable, __file__, "--one", command, str(path), str(warm)],
        check=True,
        capture_output=True,
        text=True,
        env=env,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", default="2,10,60", help="comma-separated log lengths, minutes")
    parser.add_argument("--dir", default="/tmp/online_backlash_bench", help="where the CSV logs are cached")
    parser.add_argument("--reference", metavar="DIR", help="a staged package folder timed beside this tree")
    parser.add_argument("--rounds", type=int, default=1, help="times every length is timed (trees alternating)")
    parser.add_argument("--one", nargs=3, metavar=("COMMAND", "LOG", "WARM_LOG"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        one(args.one[0], Path(args.one[1]), Path(args.one[2]))
        return
    directory = Path(args.dir)
    directory.mkdir(parents=True, exist_ok=True)
    warm = write_log(WARM_MINUTES, directory)
    load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
        f"Python {platform.python_version()}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
        f"load average {load}\n"
    )
    trees = [("this tree", None)] + ([("reference", args.reference)] if args.reference else [])
    print(
        "| round | tree | log | samples | batch wall, s (1st, 2nd) | batch CPU, s | diagnose wall, s (1st, 2nd) "
        "| diagnose CPU, s | ratio wall (1st, 2nd) | ratio CPU (1st, 2nd) | terms found | load after |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for minutes in (float(m) for m in args.minutes.split(",")):
        path = write_log(minutes, directory)
        for round_ in range(1, args.rounds + 1):
            for tree, package in trees:
                print(
                    row(
                        round_,
                        tree,
                        minutes,
                        timed("estimate", path, warm, package),
                        timed("diagnose", path, warm, package),
                    ),
                    flush=True,
                )


def row(round_: int, tree: str, minutes: float, batch: dict, diag: dict) -> str:
    """One line of the table: the two commands' times (:func:`one`) and their ratios."""
    d = json.loads(diag["stdout"])
    found = [e["name"] for e in d["effects"]] + [f"({e['name']})" for e in d["unexplained"]]

    def pair(values: list[float]) -> str:
        return ", ".join(f"{v:.2f}" for v in values)

    return (
        f"| {round_} | {tree} | {minutes:g} min | {d['samples']} | {pair(batch['wall'])} | {pair(batch['cpu'])} "
        f"| {pair(diag['wall'])} | {pair(diag['cpu'])} "
        f"| {pair([a / b for a, b in zip(diag['wall'], batch['wall'])])} "
        f"| {pair([a / b for a, b in zip(diag['cpu'], batch['cpu'])])} "
        f"| {', '.join(found) or '-'} | {os.getloadavg()[0]:.1f} |"
    )


if __name__ == "__main__":
    main()
