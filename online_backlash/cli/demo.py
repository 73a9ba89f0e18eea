"""``online-backlash demo``: the main job on a recording bundled with the package (no rig needed)."""

from __future__ import annotations

import argparse
from importlib import resources

from ..fitting import describe, fit_batch
from ..plotting import plot_characteristic
from ..replay import read_csv_arrays
from ..stream import refer_to_load

#: The bundled log (made by scripts/make_demo_log.py): 30:1 gearbox, 0.50 deg play, encoder counts.
DEMO_LOG = "demo_rig_30to1.csv.gz"
DEMO_OPTIONS = {"units": "counts", "motor_cpr": 2**14, "load_cpr": 2**17}
DEMO_RATIO = 30.0


def add_subparser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="run the main job on a bundled recording (no rig needed)",
        description="Estimate the backlash of a bundled 30:1 gearbox recording (true play 0.50 deg) and plot the fit.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--plot", default="backlash-demo.png", help="where to write the plot (PNG)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    with resources.as_file(resources.files("online_backlash") / "data" / DEMO_LOG) as path:
        chunk = read_csv_arrays(path, **DEMO_OPTIONS)
        report, est = fit_batch(chunk, DEMO_RATIO)
        print(f"bundled recording: 30:1 gearbox, true play 0.500 deg ({DEMO_LOG})")
        print(describe(report, path.name))
    u = refer_to_load(chunk.motor_deg, DEMO_RATIO)
    plot_characteristic(u, chunk.load_deg, est.predict(u, chunk.load_deg[0]), args.plot, "online-backlash demo: 30:1 gearbox")
    print(f"plot:           {args.plot}")
    return 0
