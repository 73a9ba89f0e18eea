"""Does what ``diagnose`` finds on the measured runs hang on the last bits of its base fit?

For each of the three da Vinci recordings in ``../shared/data/davinci_tool_gearhead_backlash`` and
each relative change ``e`` (default 0, +-1e-12, +-1e-9, +-1e-7), ``diagnose`` runs with the base
fit's left slope and width nudged, ``m_left * (1 + e)`` and ``c_left * (1 - e)`` (the rest as fitted),
and one line per run prints the terms found, the RMS after and the play after. A loop whose answer
is a property of the data prints the same line for every ``e``; before the switching simulation kept
the engaged state at repeated inputs (``docs/closing-the-loop.md``, "Ties on quantised data") run00
and run20 gave two to four terms and run20's play moved from 1.50 to 1.77 deg.

``--blas-threads N`` runs the loop on N BLAS threads instead of the one it pins itself to
(``loop.ONE_BLAS_THREAD``): the same question for the order in which BLAS sums.

Run: ``python bench/base_fit_nudge.py`` (about 30 s); ``--changes 0,1e-9`` and ``--runs run20`` shrink it.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
from pathlib import Path
from typing import Any

from same_results import DAVINCI, SHARED  # the README's call of the measured runs, as the outputs compared
from threadpoolctl import threadpool_limits

from online_backlash.cli import main as cli
from online_backlash.diagnostics import loop
from online_backlash.model import BacklashParams

DATA = SHARED
RUNS = {
    "run00": "tool4_L_run00_0.1Hz_torque10pct.csv",
    "run20": "tool4_L_run20_0.3Hz_torque10pct.csv",
    "run49": "tool4_L_run49_0.5Hz_torque100pct.csv",
}
ARGS = [*DAVINCI, "--json"]


def diagnosed(path: Path, change: float, blas_threads: int | None = None) -> dict[str, Any]:
    """``diagnose --json`` on ``path`` with the base fit's ``m_left``, ``c_left`` nudged by ``change``
    (relative), on ``blas_threads`` BLAS threads (None: the loop's own one)."""
    fit, pinned = loop.VorosBacklash.fit, loop.diagnose

    def nudged(self: Any, u: Any, y: Any) -> Any:
        est = fit(self, u, y)
        p = est.params_
        est.params_ = BacklashParams(p.m_left * (1 + change), p.c_left * (1 - change), p.m_right, p.c_right)
        return est

    loop.VorosBacklash.fit = nudged  # type: ignore[method-assign]
    if blas_threads is not None:
        loop.diagnose = pinned.__wrapped__  # type: ignore[attr-defined]  # the loop without its pin (the CLI imports it at the call)
    try:
        out = io.StringIO()
        with contextlib.redirect_stdout(out), threadpool_limits(limits=blas_threads, user_api="blas"):
            if cli(["diagnose", str(path), *ARGS]):
                raise SystemExit(f"diagnose failed on {path}")
        return json.loads(out.getvalue())
    finally:
        loop.VorosBacklash.fit, loop.diagnose = fit, pinned  # type: ignore[method-assign]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--changes", default="0,1e-12,-1e-12,1e-9,-1e-9,1e-7,-1e-7", help="comma-separated relative changes"
    )
    parser.add_argument("--runs", default=",".join(RUNS), help="comma-separated subset of " + ",".join(RUNS))
    parser.add_argument(
        "--blas-threads", type=int, default=None, help="BLAS threads for the loop (default: its own pin to one)"
    )
    args = parser.parse_args()
    print("| recording | change | terms in the order added | RMS after, deg | play after, deg |")
    print("|---|---|---|---|---|")
    for run in args.runs.split(","):
        for change in (float(c) for c in args.changes.split(",")):
            d = diagnosed(DATA / RUNS[run], change, args.blas_threads)
            terms = [e["name"] for e in d["effects"]] + [f"unexplained {e['name']}" for e in d["unexplained"]]
            print(
                f"| {run} | {change:g} | {', '.join(terms)} | {d['rms_after_deg']:.6f} | "
                f"{d['backlash_after_deg']:.6f} |"
            )


if __name__ == "__main__":
    main()
