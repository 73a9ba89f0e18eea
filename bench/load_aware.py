"""Load-aware play (issue 12): the two-mass sweep over the external torque, and the measured runs.

(a) The two-mass rig (:mod:`online_backlash.simulation.two_mass_rig`: 30:1, 1 kHz, 14-bit motor, 17-bit
load, play 0.4 deg, stiffness 0.1 N m/arcmin, torque noise 0.005 N m, a 30 deg sine at 0.5 Hz
against a viscous load and a constant external torque) for external torques from 0 to above the
largest torque the motion needs (the torque stops reversing at about 0.5 N m), several seeds.
Per torque: how often the torque reverses, the torque-aware play (batch ``TorqueBacklash`` and
recursive ``TorqueBacklashRLS``) and stiffness errors where it does, ``play_observable`` where it
does not, and side by side what the kinematic estimators report on the same logs without the
torque column (``VorosBacklash`` batch, ``BacklashRLS`` recursive; with the kinematic
observability of ``DwellTracker``).

(b) The three shared measured runs (da Vinci tool gearhead, ODbL v1.0: MRDLab
mis-tool-characterization, J. J. O'Neill, T. K. Stephens, T. M. Kowalewski, IEEE RA-L 3(4)
3027-3034, 2018), batch and recursive: the path the data choose and its play (issue 27), and the
torque path asked for by name (``play_method="torque"``): its torque reversals, its play or why it is
not reported, lost motion, stiffness and hysteresis loss; ``--plot DIR`` writes the torque path's
hysteresis curves.

Run: ``python bench/load_aware.py`` (about 1 minute on 2 cores); ``--seeds``, ``--duration-s``.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from online_backlash.log_fit import fit_batch, fit_recursive
from online_backlash.plotting import plot_fit
from online_backlash.replay import open_log
from online_backlash.simulation.two_mass_rig import simulate_two_mass
from online_backlash.stream import SampleChunk, read_all

TORQUES = (0.0, 0.1, 0.2, 0.3, 0.4, 0.45, 0.5, 0.6, 0.8, 1.0)
PLAY = 0.4
STIFFNESS = 0.1
DAVINCI = Path(__file__).resolve().parents[2] / "shared" / "data" / "davinci_tool_gearhead_backlash"
DAVINCI_OPTIONS = {
    "columns": {"time": "time_s", "motor": "motor_counts", "load": "spindle_counts", "torque": "backend_torque_Nm"},
    "units": "counts", "motor_cpr": 4096 * 35, "load_cpr": 8192,
}  # fmt: skip
ATTRIBUTION = (
    "Data: MRDLab mis-tool-characterization (O'Neill, Stephens, Kowalewski, IEEE RA-L 3(4) 2018), "
    "ODbL v1.0 / DbCL v1.0; this plot is a derived database work under ODbL v1.0."
)


def _without_torque(chunk: SampleChunk) -> SampleChunk:
    return SampleChunk(chunk.time_s, chunk.motor_deg, chunk.load_deg, np.full(len(chunk), np.nan), chunk.after_gap)


def _err(value: float | None, true: float) -> float:
    return math.nan if value is None or not math.isfinite(value) else 100.0 * (value - true) / true


def _fmt(values: list[float], digits: int = 2) -> str:
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return "-"
    worst = max(finite, key=abs)
    return f"{np.median(finite):+.{digits}f} / {worst:+.{digits}f}"


def sweep(seeds: int, duration_s: float) -> None:
    print("## (a) two-mass rig: play 0.4 deg, stiffness 0.1 N m/arcmin\n")
    print(
        "| external torque N m | torque reverses | observable (batch, recursive) | play err % batch (median / worst) "
        "| play err % recursive | stiffness err % (mean of both) | stiffness err % per direction (worst) "
        "| kinematic batch play deg (median; reported null where not observable) | kinematic recursive play deg | "
        "kinematic observable |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for ext in TORQUES:
        rows: dict[str, list] = {
            k: [] for k in ("rev", "obs_b", "obs_r", "pb", "pr", "k", "kdir", "kin_b", "kin_r", "kin_obs")
        }
        for seed in range(seeds):
            rec = simulate_two_mass(duration_s=duration_s, play_deg=PLAY, external_torque_nm=ext, seed=seed)
            chunk = rec.to_chunk()
            batch, _ = fit_batch(chunk, rec.ratio)
            rls, _ = fit_recursive([chunk], rec.ratio)
            kin_b, kin_b_est = fit_batch(_without_torque(chunk), rec.ratio)
            _, kin_r_est = fit_recursive([_without_torque(chunk)], rec.ratio)
            rows["rev"].append(rec.reversals_of_torque > 0)
            rows["obs_b"].append(batch.play_observable)
            rows["obs_r"].append(rls.play_observable)
            rows["pb"].append(_err(batch.backlash_deg, PLAY))
            rows["pr"].append(_err(rls.backlash_deg, PLAY))
            rows["k"] += [_err(r.stiffness_nm_per_arcmin, STIFFNESS) for r in (batch, rls) if r.play_observable]
            rows["kdir"] += [
                _err(v, STIFFNESS)
                for r in (batch, rls)
                for v in (r.stiffness_left_nm_per_arcmin, r.stiffness_right_nm_per_arcmin)
            ]
            rows["kin_b"].append(kin_b_est.backlash_)  # what the kinematic fit says, observable or not
            rows["kin_r"].append(kin_r_est.estimator.backlash_)  # the estimator itself, before the verdict
            rows["kin_obs"].append(kin_b.play_observable)
        kin = [f"{np.nanmedian(np.asarray(rows[k], dtype=float)):.3f}" for k in ("kin_b", "kin_r")]
        print(
            f"| {ext:.2f} | {sum(rows['rev'])}/{seeds} | {sum(rows['obs_b'])}/{seeds}, {sum(rows['obs_r'])}/{seeds} "
            f"| {_fmt(rows['pb'])} | {_fmt(rows['pr'])} | {_fmt(rows['k'], 1)} | {_fmt(rows['kdir'], 1)} "
            f"| {kin[0]} | {kin[1]} | {sum(rows['kin_obs'])}/{seeds} |"
        )


def _value(d: dict, key: str, scale: float = 1.0, digits: int = 3) -> str:
    v = d.get(key)
    return "null" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v * scale:.{digits}f}"


def measured(plot_dir: Path | None) -> None:
    print(
        "\n## (b) measured da Vinci gearhead runs (ODbL v1.0; ratio -1 on output-referred motor counts, slope fitted)\n"
    )
    print(
        "| run | method | path taken | play deg | torque path: reversals | its play deg (or why not) "
        "| lost motion arcmin (at N m) | stiffness N m/arcmin (left, right) | hysteresis loss arcmin |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for path in sorted(DAVINCI.glob("*.csv")):
        with open_log(path, **DAVINCI_OPTIONS) as log:
            chunk = read_all(log, path)
        for method in ("batch", "recursive"):
            auto, torque = (
                (fit_batch(chunk, -1.0, play_method=m)[0] for m in ("auto", "torque"))
                if method == "batch"
                else (fit_recursive([chunk], -1.0, memory_reversals=None, play_method=m)[0] for m in ("auto", "torque"))
            )
            a, d = auto.as_dict(), torque.as_dict()
            why_not = d["reason"].split(":")[0] if d["reason"] else ""
            print(
                f"| {path.stem} | {method} | {a['play_method']} | {_value(a, 'backlash_deg')} "
                f"| {d['torque_reversals']} "
                f"| {_value(d, 'backlash_deg')} {why_not} "
                f"| {_value(d, 'lost_motion_arcmin', digits=1)} ({_value(d, 'lost_motion_torque_Nm', digits=3)}) "
                f"| {_value(d, 'stiffness_left_nm_per_arcmin', digits=4)}, "
                f"{_value(d, 'stiffness_right_nm_per_arcmin', digits=4)} "
                f"| {_value(d, 'hysteresis_loss_arcmin', digits=1)} |"
            )
        if plot_dir is not None:
            out = plot_dir / f"hysteresis_{path.stem}.png"
            plot_fit(chunk, -1.0, out, title=path.stem, note=ATTRIBUTION, play_method="torque")
            print(f"\nplot: {out}\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--duration-s", type=float, default=20.0)
    parser.add_argument("--plot", type=Path, metavar="DIR", help="write the measured runs' hysteresis curves here")
    args = parser.parse_args()
    start = time.perf_counter()
    sweep(args.seeds, args.duration_s)
    measured(args.plot)
    print(f"\n{time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
