"""A play you can trust on synthetic drives (issue 27): what the rules do where the truth is known.

(a) The two-mass rig (:mod:`online_backlash.simulation.two_mass_rig`, play 0.4 deg, 30:1, 1 kHz, 20 s, a 30 deg
sine at 0.5 Hz, 5 seeds) with what a real drive adds: a torque sensor with a zero offset and a
friction torque between it and the flanks, a soft spring, Coulomb friction on the load. The torque
path that takes zero torque as "no flank touches" (before issue 27) beside the one that estimates
the engagement torques from the dwells, batch and recursive, and the path ``auto`` takes.

(b) A hardening spring (data-sheet segments K1 0.02, K2 0.05, K3 0.12 N m/arcmin, T1 0.08, T2 0.25
N m): one straight wind-up line, then the three segments (``stiffness_torques_Nm``).

(c) Plays of 0, 0.5 arcsec, 5 arcsec, 0.5 and 1 arcmin at 14-, 17- and 20-bit encoders (the kinematic
rig, :mod:`online_backlash.simulation.rig`, 20 s, 2 counts of load-encoder noise): what batch, recursive and
``track`` report, and what share of the samples the full-engagement rule leaves out.

(d) A train with two gaps in series (``second_gap_deg``: 0.25 + 0.15 deg, stiff meshes, 1 N m/arcmin) whose
load a torque ``-T (1 - sin wt) / 2`` holds across the second gap over part of every rising stroke (issue 27 item 5,
the measured gearhead's two-step crossing): the angles alone, batch, recursive and ``track``, against the
paper's lines with every sample (``full_engagement=False``); the rig's angles have no noise, so one run each.

Run: ``python bench/play_rules.py`` (about 10 s on 2 cores).
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from online_backlash import VorosBacklash
from online_backlash.estimators.full_engagement import NO_FLANK, FullEngagement
from online_backlash.history.store import HistoryStore
from online_backlash.load_aware import TorqueBacklash
from online_backlash.log_fit import fit_batch, fit_recursive
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.two_mass_rig import simulate_two_mass
from online_backlash.stream import SampleChunk
from online_backlash.tracking import GearboxTracker

PLAY = 0.4
SENSOR = {"play_deg": PLAY, "stiffness_nm_per_arcmin": 0.02, "coulomb_nm": 0.03}
CASES = (
    ("zero offset, no friction", {}),
    ("offset 0.05 N m", {"sensor_offset_nm": 0.05}),
    ("friction 0.05 N m", {"sensor_friction_nm": 0.05}),
    ("offset 0.03, friction 0.05 N m", {"sensor_offset_nm": 0.03, "sensor_friction_nm": 0.05}),
)
HARD = {"stiffness_segments": ((0.02, 0.05, 0.12), (0.08, 0.25)), "coulomb_nm": 0.03, "viscous_nms_per_rad": 1.0}


def _pct(values: list[float]) -> str:
    errors = [100.0 * (v - PLAY) / PLAY for v in values if v is not None and math.isfinite(v)]
    return "-" if not errors else f"{np.median(errors):+.1f} / {max(errors, key=abs):+.1f}"


def sensor(seeds: int) -> None:
    print("## (a) a torque sensor behind friction, with a zero offset (play err %, median / worst)\n")
    print(
        "| sensor | zero-torque model, batch | batch | recursive | path taken (batch, recursive) "
        "| engagement torques N m |"
    )
    print("|---|---|---|---|---|---|")
    for name, extra in CASES:
        old, batch, rec, paths, eng = [], [], [], [], []
        for seed in range(seeds):
            r = simulate_two_mass(duration_s=20.0, seed=seed, **SENSOR, **extra)
            old.append(TorqueBacklash().fit(r.motor_deg / r.ratio, r.load_deg, r.torque_Nm).backlash_)
            b, c = fit_batch(r.to_chunk(), r.ratio)[0].as_dict(), fit_recursive([r.to_chunk()], r.ratio)[0].as_dict()
            batch.append(b["backlash_deg"])
            rec.append(c["backlash_deg"])
            paths.append(f"{b['play_method']}, {c['play_method']}")
            eng.append((b["engagement_torque_left_Nm"], b["engagement_torque_right_Nm"]))
        left, right = np.median(eng, axis=0)
        taken = ", ".join(f"{paths.count(p)}x {p}" for p in sorted(set(paths)))
        print(f"| {name} | {_pct(old)} | {_pct(batch)} | {_pct(rec)} | {taken} | {left:+.3f}, {right:+.3f} |")


def hardening() -> None:
    print("\n## (b) a hardening spring: one straight line against the data sheet's three segments\n")
    print("| fit | path | play deg | std deg | K1, K2, K3 N m/arcmin | segments fitted | hysteresis loss arcmin |")
    print("|---|---|---|---|---|---|---|")
    rec = simulate_two_mass(duration_s=20.0, play_deg=PLAY, seed=2, **HARD)
    for name, kwargs in (
        ("auto, one line", {}),
        ("torque path, one line", {"play_method": "torque"}),
        ("three segments", {"stiffness_torques_Nm": (0.08, 0.25)}),
    ):
        d = fit_batch(rec.to_chunk(), rec.ratio, **kwargs)[0].as_dict()
        k = [d.get(f"stiffness_k{i}_nm_per_arcmin") for i in (1, 2, 3)]
        shown = ", ".join("-" if v is None else f"{v:.4f}" for v in k)
        hyst = d["hysteresis_loss_arcmin"]
        print(
            f"| {name} | {d['play_method']} | {d['backlash_deg']:.4f} | {d['backlash_std_deg']:.4f} | {shown} "
            f"| {', '.join(d['stiffness_segments_fitted']) or '-'} | {'-' if hyst is None else f'{hyst:.1f}'} |"
        )


def _tracked(chunk: SampleChunk, every_s: float) -> dict:
    """The last estimate ``track`` stores for one log into a fresh store."""
    with tempfile.TemporaryDirectory() as folder, HistoryStore(Path(folder) / "w.db", create=True) as store:
        tracker = GearboxTracker(store, "g", 30.0, every_s=every_s)
        tracker.track_chunks([chunk], "log", key="k" * 64, clock_offset=lambda first: 1.7e9 - first)
        return vars(store.estimates("g")[-1])


def _left_out(motor_deg: np.ndarray, load_deg: np.ndarray, ratio: float) -> str:
    """The share of the samples the full-engagement rule puts on neither flank line."""
    return f"{np.mean(FullEngagement().fit(motor_deg / ratio, load_deg) == NO_FLANK):.1%}"


def zero_play() -> None:
    print("\n## (c) zero and sub-resolution play: play +- std, or 0 with the upper bound (arcmin)\n")
    print("| encoders | true play arcmin | batch | recursive | track (last estimate) | left out |")
    print("|---|---|---|---|---|---|")
    for bits in (14, 17, 20):
        for arcmin in (0.0, 0.5 / 60, 5 / 60, 0.5, 1.0):
            rec = simulate_rig(duration_s=20.0, play_deg=arcmin / 60, motor_bits=bits, load_bits=bits, seed=bits)
            chunk = rec.to_chunk()
            shown = [fit_batch(chunk, 30.0)[0].as_dict(), fit_recursive([chunk], 30.0)[0].as_dict()]
            shown.append(_tracked(chunk, 5.0))
            cells = [
                f"0 (at most {60 * d['backlash_upper_bound_deg']:.3f})"
                if d["backlash_deg"] == 0.0
                else f"{60 * d['backlash_deg']:.3f} +- {60 * d['backlash_std_deg']:.3f}"
                for d in shown
            ]
            left_out = _left_out(rec.motor_deg, rec.load_deg, 30.0)
            print(f"| {bits} bit | {arcmin:.4f} | {' | '.join(cells)} | {left_out} |")


def _angles_only(chunk: SampleChunk) -> SampleChunk:
    return SampleChunk(chunk.time_s, chunk.motor_deg, chunk.load_deg, np.full(len(chunk), np.nan), chunk.after_gap)


def two_gaps() -> None:
    print("\n## (d) two gaps in series, the second held open over part of the rising stroke (play deg +- std)\n")
    print("| T N m | sine Hz | paper's lines, every sample | batch | recursive | track | left out |")
    print("|---|---|---|---|---|---|---|")
    for overrun, hz in ((0.0, 0.5), (0.3, 0.5), (0.3, 0.2), (0.5, 0.5)):
        rec = simulate_two_mass(
            duration_s=20.0, play_deg=PLAY, second_gap_deg=0.15, stiffness_nm_per_arcmin=1.0, viscous_nms_per_rad=0.05,
            frequency_hz=hz, external_torque_nm=lambda t, a=overrun, f=hz: -a * (1.0 - np.sin(2 * np.pi * f * t)) / 2,
        )  # fmt: skip
        paper = VorosBacklash(origin="first").fit(rec.motor_deg / rec.ratio, rec.load_deg)
        chunk = _angles_only(rec.to_chunk())
        found = [fit_batch(chunk, rec.ratio)[0].as_dict(), fit_recursive([chunk], rec.ratio)[0].as_dict()]
        found.append(_tracked(chunk, 10.0))
        cells = [f"{d['backlash_deg']:.4f} +- {d['backlash_std_deg']:.4f}" for d in found]
        left_out = _left_out(rec.motor_deg, rec.load_deg, rec.ratio)
        print(f"| {overrun} | {hz} | {paper.backlash_:.4f} | {' | '.join(cells)} | {left_out} |")


def main() -> None:
    start = time.perf_counter()
    sensor(5)
    hardening()
    zero_play()
    two_gaps()
    print(f"\n{time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
