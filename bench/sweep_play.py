"""One drive, one play (issue 27 item 5): the 50-run sweep of one da Vinci gearhead, play per run.

The sweep (``shared/data/davinci_tool_gearhead_backlash/sweep/``, ODbL v1.0: MRDLab
mis-tool-characterization, J. J. O'Neill, T. K. Stephens, T. M. Kowalewski, IEEE RA-L 3(4)
3027-3034, 2018) is 5 sine frequencies x 10 reaction-torque settings of one gearhead on one day:
its play is one physical number. Every run goes through the call the README teaches, with the torque
column given, in this process (``online_backlash.cli.main``):

    online-backlash estimate RUN --ratio -35 \
        --columns time=time_s,motor=motor_counts,load=spindle_counts,torque=backend_torque_Nm
        --units counts --motor-cpr 4096 --load-cpr 8192 --json                     (recursive, the default)

and the same with ``--method batch``, and ``track`` into a fresh SQLite store (``--every 10``: a whole
number of periods at every frequency; the last stored estimate). Printed per run: the play, its std, the
path taken and why (or why it is not reported), beside the figures of the code before issue 27
(``bench/sweep_play_before.csv``: the same call with and without the torque column, written at commit
3372d26 by ``--write-before``). Then the acceptance of the issue on the recursive (README) call:

* every run reports a physical play or "not observable" with a reason;
* at least 45 runs observable;
* the observable plays within 15 % of their median (``max - min <= 0.15 median``);
* each run's +-2 std covers that median in at least 90 % of the runs;
* the recursive estimate and ``track`` agree with the batch one within the batch's stated std.

Run: ``python bench/sweep_play.py`` (under 30 s on 2 cores; ``--runs 0,20,49`` for some): prints the tables
of ``docs/load-aware.md`` (the runs, the acceptance).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import math
import statistics
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from online_backlash.cli import main

SWEEP = Path(__file__).resolve().parents[2] / "shared" / "data" / "davinci_tool_gearhead_backlash" / "sweep"
BEFORE = Path(__file__).with_name("sweep_play_before.csv")
WITH_TORQUE = "time=time_s,motor=motor_counts,load=spindle_counts,torque=backend_torque_Nm"
WITHOUT_TORQUE = "time=time_s,motor=motor_counts,load=spindle_counts"
UNITS = ["--ratio", "-35", "--units", "counts", "--motor-cpr", "4096", "--load-cpr", "8192"]
#: The issue's acceptance: observable runs, spread about the median, coverage of the median by +-2 std.
MIN_OBSERVABLE, MAX_SPREAD, MIN_COVERAGE = 45, 0.15, 0.90


def runs(selected: list[int] | None = None) -> list[Path]:
    """The sweep's runs in order (``selected``: their numbers)."""
    paths = sorted(SWEEP.glob("tool4_L_run*.csv.gz"))
    return [p for p in paths if selected is None or int(p.name[11:13]) in selected]


def _quiet(argv: list[str]) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = main(argv)
    if code != 0:
        raise RuntimeError(f"online-backlash {' '.join(argv)} exited {code}")
    return out.getvalue()


def estimate(path: Path, columns: str = WITH_TORQUE, *extra: str) -> dict[str, Any]:
    """``estimate --json`` of one run (in this process)."""
    return json.loads(_quiet(["estimate", str(path), *UNITS, "--columns", columns, "--json", *extra]))


def tracked(path: Path, folder: Path) -> dict[str, Any]:
    """The last estimate ``track`` stores for one run tracked alone into a fresh SQLite store."""
    from online_backlash.history.store import HistoryStore

    db = folder / f"{path.stem}.db"
    _quiet(
        [
            "track",
            str(path),
            *UNITS,
            "--columns",
            WITH_TORQUE,
            "--db",
            str(db),
            "--gearbox",
            "gh",
            "--every",
            "10",
            "--quiet",
        ]
    )
    with HistoryStore(db) as store:
        return vars(store.estimates("gh")[-1])


@dataclass
class Run:
    """One run's figures (degrees; None where not reported)."""

    name: str
    play: float | None
    std: float | None
    method: str
    reason: str
    observable: bool
    batch: float | None
    batch_std: float | None
    track: float | None
    lower: float | None
    upper: float | None


def measure(path: Path, folder: Path) -> Run:
    rec, bat, trk = estimate(path), estimate(path, WITH_TORQUE, "--method", "batch"), tracked(path, folder)
    why = rec["reason"] if rec["backlash_deg"] is None else rec["play_method_reason"]
    return Run(
        path.name[:-7], rec["backlash_deg"], rec["backlash_std_deg"], rec["play_method"], why or "",
        rec["play_observable"], bat["backlash_deg"], bat["backlash_std_deg"], trk["backlash_deg"],
        rec["backlash_lower_bound_deg"], rec["backlash_upper_bound_deg"],
    )  # fmt: skip


def acceptance(results: list[Run]) -> dict[str, Any]:
    """The issue's acceptance figures over the runs (module docstring)."""
    physical = all(
        (r.play is not None and r.play >= 0 and r.std is not None and math.isfinite(r.std))
        or (not r.observable and r.reason)
        for r in results
    )
    seen = [r for r in results if r.play is not None]
    plays = [r.play for r in seen if r.play is not None]
    median = statistics.median(plays) if plays else math.nan
    spread = (max(plays) - min(plays)) / median if plays else math.nan
    covered = [abs(r.play - median) <= 2 * r.std for r in seen if r.play is not None and r.std is not None]
    agree_rec = [
        abs(r.play - r.batch) <= r.batch_std
        for r in seen
        if r.batch is not None and r.batch_std is not None and r.play is not None
    ]
    agree_trk = [
        abs(r.track - r.batch) <= r.batch_std
        for r in seen
        if r.track is not None and r.batch is not None and r.batch_std is not None
    ]
    figures = {
        "runs": len(results), "physical_or_reasoned": physical, "observable": len(seen), "median_deg": median,
        "spread": spread,
        "coverage": sum(covered) / len(covered) if covered else math.nan,
        "recursive_within_batch_std": f"{sum(agree_rec)}/{len(agree_rec)}",
        "track_within_batch_std": f"{sum(agree_trk)}/{len(agree_trk)}",
    }  # fmt: skip
    figures["met"] = bool(
        physical and len(seen) >= min(MIN_OBSERVABLE, len(results) - 5 * (len(results) < 50)) and spread <= MAX_SPREAD
        and figures["coverage"] >= MIN_COVERAGE and all(agree_rec) and all(agree_trk)
    )  # fmt: skip
    return figures


def _num(value: Any, digits: int = 3) -> str:
    return (
        "null"
        if value is None or (isinstance(value, float) and not math.isfinite(value))
        else f"{float(value):.{digits}f}"
    )


def read_before() -> dict[str, dict[str, str]]:
    """The figures of the code before issue 27, by run (``bench/sweep_play_before.csv``)."""
    with open(BEFORE, newline="") as f:
        return {row["run"]: row for row in csv.DictReader(line for line in f if not line.startswith("#"))}


def write_before(selected: list[Path]) -> None:
    """The figures of the code at hand for the before column: the README call with and without the torque column."""
    with open(BEFORE, "w", newline="") as f:
        f.write("# python bench/sweep_play.py --write-before, at commit 3372d26 (before issue 27); degrees\n")
        writer = csv.writer(f)
        writer.writerow(["run", "torque_play", "torque_std", "torque_observable", "kinematic_play", "kinematic_std"])
        for path in selected:
            torque, kinematic = estimate(path), estimate(path, WITHOUT_TORQUE)
            figures = [_num(d["backlash_deg"], 4) for d in (torque, kinematic)]
            stds = [_num(d.get("backlash_std_deg"), 4) for d in (torque, kinematic)]
            writer.writerow([path.name[:-7], figures[0], stds[0], torque["play_observable"], figures[1], stds[1]])
            print(path.name, flush=True)


def main_() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", help="run numbers, e.g. 0,20,49 (default: all 50)")
    parser.add_argument(
        "--write-before", action="store_true", help=f"write {BEFORE.name} with the code at hand and stop"
    )
    args = parser.parse_args()
    selected = runs(None if args.runs is None else [int(v) for v in args.runs.split(",")])
    if args.write_before:
        write_before(selected)
        return
    before = read_before()
    start = time.perf_counter()
    print(
        "| run | Hz | torque % | before: torque path play +- std | before: kinematic | play deg | std deg | path | why "
        "| batch play +- std | track |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    results = []
    with tempfile.TemporaryDirectory() as folder:
        for path in selected:
            r = measure(path, Path(folder))
            results.append(r)
            b = before.get(r.name, {})
            number, hz, setting = r.name[11:13], r.name.split("_")[3][:-2], r.name.split("_")[4][6:-3]
            print(
                f"| {number} | {hz} | {setting} | {b.get('torque_play', '-')} +- {b.get('torque_std', '-')} "
                f"| {b.get('kinematic_play', '-')} | {_num(r.play)} | {_num(r.std)} | {r.method} | {_why(r)} "
                f"| {_num(r.batch)} +- {_num(r.batch_std)} | {_num(r.track)} |",
                flush=True,
            )
    print_acceptance(acceptance(results))
    print(f"\n{time.perf_counter() - start:.0f} s")


def _why(r: Run) -> str:
    """The path's reason in a few words: the torque model missed the dwells, or its play was not resolved."""
    if r.play is None:
        return r.reason
    if r.reason.startswith("the torque does not fit the motion"):
        return "dwells"
    if r.reason.startswith("the torque path's play is not physical"):
        return "torque play not resolved"
    return r.reason.split(":")[0]


def print_acceptance(figures: dict[str, Any]) -> None:
    """The issue's acceptance as the table of docs/load-aware.md."""
    n = figures["runs"]
    print("\n| criterion | required | result |\n|---|---|---|")
    reasoned = figures["physical_or_reasoned"]
    print(f'| every run a physical play or "not observable" with a reason | all | {reasoned} |')
    print(f"| observable runs | >= {MIN_OBSERVABLE} of 50 | {figures['observable']} of {n} |")
    print(
        f"| observable plays within {MAX_SPREAD:.0%} of their median (max - min <= {MAX_SPREAD} median) "
        f"| <= {MAX_SPREAD} | {figures['spread']:.3f} (median {figures['median_deg']:.3f} deg) |"
    )
    print(f"| each run's +-2 std covers the median | >= {MIN_COVERAGE:.0%} | {figures['coverage']:.0%} |")
    print(f"| recursive within the batch's stated std | all | {figures['recursive_within_batch_std']} |")
    print(f"| `track` within the batch's stated std | all | {figures['track_within_batch_std']} |")
    print(f"\nacceptance met: {figures['met']}")


if __name__ == "__main__":
    main_()
