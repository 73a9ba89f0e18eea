"""Accuracy of the recursive estimators: wear tracking, idle, and the paper's cascade examples.

Prints markdown tables for ``docs/benchmarks.md``:

1. **Wear.** Rig-like data (30:1, 1 kHz, 14-bit motor, 17-bit load, noise of 2 load counts,
   continuous rotation with reversals every 2-9 s) whose total play grows linearly from 0.50 to
   0.60 deg over 2 hours. After the first 5 minutes: RMS error of ``backlash_`` against the true
   play (deg, % of the play, load counts) and the share of time the truth lies inside
   ``+-3 backlash_std_`` (snapshots every second of data).
2. **Idle.** 20 minutes of such motion, one hour with the motor still (or dithering by one
   motor count against a flank), 20 minutes of motion: change of the estimate over the hour,
   covariance finite, error after the restart.
3. **Paper examples 3-5** (cascade, random input |u| < 1, 1500 samples, SNR 25) streamed through
   ``CascadeRLS`` against ``VorosCascade`` on the same data, over several noise seeds.

Run: ``python bench/recursive_accuracy.py`` (a few minutes; ``--seeds`` sets the repeats).
"""

from __future__ import annotations

import argparse
import os
import platform

import numpy as np

from online_backlash import BacklashRLS, CascadeRLS, VorosCascade
from online_backlash.model import BacklashParams, simulate_backlash_varying, simulate_cascade
from online_backlash.simulation.rig import quantise, rig_motion, simulate_rig

LOAD_COUNT_DEG = 360.0 / 2**17
HOUR_S = 3600.0


def snapshots(est: BacklashRLS, u: np.ndarray, y: np.ndarray, every: int = 1000) -> np.ndarray:
    """Learn in blocks of ``every`` samples; rows ``(last index, backlash_, backlash_std_)`` once started."""
    out = []
    for lo in range(0, u.size, every):
        hi = min(lo + every, u.size)
        est.learn_many(u[lo:hi], y[lo:hi])
        if est.started:
            out.append((hi - 1, est.backlash_, est.backlash_std_))
    return np.array(out)


def wear_case(seed: int, settings: dict, duration_s: float = 2 * HOUR_S) -> dict:
    def play(t):
        return 0.50 + 0.10 * t / duration_s

    rec = simulate_rig(duration_s=duration_s, play_deg=play, seed=seed)
    snap = snapshots(BacklashRLS(**settings), rec.motor_deg / rec.ratio, rec.load_deg)
    idx = snap[:, 0].astype(int)
    after = rec.time_s[idx] >= 300.0
    err = snap[after, 1] - rec.play_deg[idx[after]]
    std = snap[after, 2]
    rms = float(np.sqrt(np.mean(err**2)))
    return {
        "rms_deg": rms,
        "rms_pct": 100 * rms / float(np.mean(rec.play_deg[idx[after]])),
        "rms_counts": rms / LOAD_COUNT_DEG,
        "max_counts": float(np.max(np.abs(err))) / LOAD_COUNT_DEG,
        "coverage": float(np.mean(np.abs(err) <= 3 * std)),
        "mean_std_counts": float(np.mean(std)) / LOAD_COUNT_DEG,
    }


def idle_log(seed: int, dither_counts: int, motion_s: float = 1200.0, idle_s: float = HOUR_S):
    """Motion, then ``idle_s`` of a still (or dithering) motor, then motion; play 0.50 -> 0.51 deg over the motion."""
    rng = np.random.default_rng(seed)
    _, u1 = rig_motion(motion_s, seed=seed)
    _, u2 = rig_motion(motion_s, seed=seed + 100)
    n_idle = int(idle_s * 1000)
    motor_step = 360.0 / 2**14 / 30.0
    u = np.concatenate((u1, u1[-1] + dither_counts * motor_step * (np.arange(n_idle) % 2), u1[-1] + u2))
    motion_clock = np.concatenate((np.arange(u1.size), np.full(n_idle, u1.size), u1.size + np.arange(u2.size))) / 1000.0
    play = 0.50 + 0.01 * motion_clock / (2 * motion_s)
    x = simulate_backlash_varying(u, 1.0, play / 2, 1.0, play / 2)
    y = quantise(x - 321.0 + rng.normal(0, 2 * LOAD_COUNT_DEG, u.size), 17)
    motor = quantise(u * 30.0 + 1234.5, 14)
    return motor / 30.0, y, play, u1.size, u1.size + n_idle


def idle_case(seed: int, dither_counts: int, settings: dict) -> dict:
    u, y, play, start, end = idle_log(seed, dither_counts)
    est = BacklashRLS(**settings)
    est.learn_many(u[:start], y[:start])
    before, std_before = est.backlash_, est.backlash_std_
    est.learn_many(u[start:end], y[start:end])
    after, std_after = est.backlash_, est.backlash_std_
    P = est.P_local_
    est.learn_many(u[end:], y[end:])
    return {
        "change_counts": abs(after - before) / LOAD_COUNT_DEG,
        "std_before_counts": std_before / LOAD_COUNT_DEG,
        "std_after_counts": std_after / LOAD_COUNT_DEG,
        "max_P_local": float(np.max(np.abs(P))),
        "finite": bool(np.all(np.isfinite(P))),
        "final_error_counts": (est.backlash_ - play[-1]) / LOAD_COUNT_DEG,
    }


EXAMPLES = {
    3: BacklashParams(1.3, 0.6, 2.0, 0.7),
    4: BacklashParams(0.24, 0.035, 0.26, 0.07),
    5: BacklashParams(-1.3, 0.2, -1.3, 0.2),
}
A, B = [0.5], [-0.2, 0.35]


def cascade_case(example: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Relative differences recursive vs batch, recursive vs truth, batch vs truth over [mL, cL, mR, cR, a2, b1, b2]."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, 1500)
    y, _ = simulate_cascade(u, EXAMPLES[example], A, B)
    y = y + rng.normal(0, np.std(y) / 25, y.size)
    batch = VorosCascade(origin="zero").fit(u, y)
    est = CascadeRLS(origin="zero", warm_start_samples=500, memory_reversals=None)
    est.learn_many(u, y)

    def vec(e):
        return np.array([e.m_left_, e.c_left_, e.m_right_, e.c_right_, *e.a_[1:], *e.b_])

    p = EXAMPLES[example]
    truth = np.array([p.m_left, p.c_left, p.m_right, p.c_right, *A, *B])
    r, b = vec(est), vec(batch)
    return np.abs(r - b) / np.abs(b), np.abs(r - truth) / np.abs(truth), np.abs(b - truth) / np.abs(truth)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="repeats (noise and motion seeds) of the wear and idle cases")
    ap.add_argument("--cascade-seeds", type=int, default=10, help="noise seeds of each paper example")
    args = ap.parse_args()
    seeds = range(args.seeds)
    print(f"# recursive accuracy ({platform.machine()}, {os.cpu_count()} cores)\n")
    print(f"command: `python bench/recursive_accuracy.py --seeds {args.seeds} --cascade-seeds {args.cascade_seeds}`\n")

    print("## Wear: play 0.50 -> 0.60 deg over 2 h of rig data (after the first 5 min; 1 load count = 0.00275 deg)\n")
    print(
        "| settings | seed | RMS error (deg) | RMS / play | RMS (counts) | max (counts) | truth within +-3 std | "
        "mean std (counts) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    memories = (
        ("default (memory_reversals=10)", {}),
        ("memory_reversals=5", {"memory_reversals": 5}),
        ("memory_s=5, no per-reversal memory", {"memory_s": 5.0, "memory_reversals": None}),
    )
    for label, settings in memories:
        for seed in seeds:
            r = wear_case(seed, settings)
            print(
                f"| {label} | {seed} | {r['rms_deg']:.2e} | {r['rms_pct']:.3f} % | {r['rms_counts']:.3f} | "
                f"{r['max_counts']:.2f} "
                f"| {100 * r['coverage']:.1f} % | {r['mean_std_counts']:.3f} |"
            )

    print("\n## Idle: 20 min motion, 1 h motor still (or dithering one motor count), 20 min motion\n")
    print(
        "| settings | motor during the hour | seed | change over the hour (counts) | std before / after (counts) "
        "| max abs P_local_ | finite | error at the end (counts) |"
    )
    print("|---|---|---:|---:|---:|---:|---|---:|")
    for label, settings in (("default", {}), ("memory_s=5", {"memory_s": 5.0, "memory_reversals": None})):
        for dither, what in ((0, "still"), (1, "dithering 1 count")):
            for seed in seeds:
                r = idle_case(seed, dither, settings)
                print(
                    f"| {label} | {what} | {seed} | {r['change_counts']:.4f} | {r['std_before_counts']:.3f} / "
                    f"{r['std_after_counts']:.3f} "
                    f"| {r['max_P_local']:.3g} | {r['finite']} | {r['final_error_counts']:+.3f} |"
                )

    print("\n## Paper examples 3-5 streamed: CascadeRLS vs VorosCascade on the same data (1500 samples, SNR 25)\n")
    print("largest relative difference over [mL, cL, mR, cR, a2, b1, b2]\n")
    print("| example | seed | recursive vs batch | recursive vs truth | batch vs truth |")
    print("|---:|---:|---:|---:|---:|")
    diffs = []
    for example in EXAMPLES:
        for seed in range(args.cascade_seeds):
            rb, rt, bt = cascade_case(example, seed)
            diffs.append(float(rb.max()))
            print(f"| {example} | {seed} | {100 * rb.max():.2f} % | {100 * rt.max():.2f} % | {100 * bt.max():.2f} % |")
    within = sum(d <= 0.03 for d in diffs)
    print(f"\nrecursive within 3 % of batch in {within} of {len(diffs)} runs; worst {100 * max(diffs):.2f} %")


if __name__ == "__main__":
    main()
