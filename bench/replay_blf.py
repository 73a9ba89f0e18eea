"""Replay of a 1,000,000-frame BLF log: our reader (decode + check + pair) beside a bare
``can.LogReader`` loop over the same file, in one run.

The log is the simulated 30:1 rig (:func:`online_backlash.simulation.rig.simulate_rig`) at 2 kHz with motor
and load in two messages of the shipped ``rig.dbc`` (``MotorAngle``, ``LoadAngle``: counter and
CRC-8 checksum), so 1,000,000 frames are 500,000 samples. The loops run interleaved,
``--repeat`` times each, and the best time of each is reported (the machine is shared).

``CanLog.iter_chunks()`` is what ``estimate`` and the estimators' ``learn_many`` use (the block
path: arrays, vectorised decoding and checksum, compiled pairing); iterating ``CanLog`` gives
``Sample`` objects from the same path; ``strict=True`` takes the per-frame path (held equal
to the block path by ``tests/test_can_blocks.py``). The first block-path run of a process also loads numba's compiled
pairing loop (printed separately; the best-of times exclude it after the first repeat).

    python bench/replay_blf.py [--frames 1000000] [--repeat 3] [--path /tmp/rig-1M.blf]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import can

from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.codecs.options import CanDecoding, FrameRules
from online_backlash.replay.canlog import CanLog
from online_backlash.simulation.rig_logs import write_rig_can_log

SIGNALS = ("MotorAngle.Count", "LoadAngle.Count")


def bare(path: str) -> tuple[int, int]:
    n = 0
    for _ in can.LogReader(path):
        n += 1
    return n, 0


def bare_decode(path: str) -> tuple[int, int]:
    """The bare loop plus cantools' decode of our two messages: the floor of any DBC decoding."""
    db = DbcDecoder(RIG_DBC, *SIGNALS).db
    decoders = {m.frame_id: m.decode_simple for m in db.messages}
    n = 0
    for msg in can.LogReader(path):
        decoders[msg.arbitration_id](msg.data, False, False)
        n += 1
    return n, 0


def chunks(path: str, checksum: str | None) -> tuple[int, int]:
    log = CanLog(path, CanDecoding(RIG_DBC, *SIGNALS, checksum_signal=checksum))
    n = sum(len(chunk) for chunk in log.iter_chunks())
    return log.counters.frames, n


def sample_objects(path: str, strict: bool = False) -> tuple[int, int]:
    log = CanLog(path, CanDecoding(RIG_DBC, *SIGNALS), frames=FrameRules(strict=strict))
    n = 0
    for _ in log:
        n += 1
    return log.counters.frames, n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--path", default="/tmp/online-backlash-rig-1M.blf")
    args = ap.parse_args()
    if not os.path.exists(args.path):
        t = time.perf_counter()
        write_rig_can_log(args.path, duration_s=args.frames / 2 / 2000.0, rate_hz=2000.0, seed=0)
        print(f"wrote {args.path} ({os.path.getsize(args.path) / 2**20:.1f} MiB) in {time.perf_counter() - t:.0f} s")
    loops = {
        "bare can.LogReader loop": lambda: bare(args.path),
        "bare loop + cantools decode only": lambda: bare_decode(args.path),
        "CanLog.iter_chunks() (default)": lambda: chunks(args.path, "Checksum"),
        "CanLog.iter_chunks(), no checksum": lambda: chunks(args.path, None),
        "iter(CanLog): Sample objects": lambda: sample_objects(args.path),
        "per-frame path (strict=True)": lambda: sample_objects(args.path, strict=True),
    }
    t0 = time.perf_counter()
    chunks(args.path, "Checksum")
    print(
        "first block-path run in this process (includes loading or compiling the numba loop): "
        f"{time.perf_counter() - t0:.2f} s"
    )
    best: dict[str, float] = {}
    counts: dict[str, tuple[int, int]] = {}
    for _ in range(args.repeat):
        for name, loop in loops.items():
            t0 = time.perf_counter()
            counts[name] = loop()
            best[name] = min(best.get(name, float("inf")), time.perf_counter() - t0)
    base = best["bare can.LogReader loop"]
    print(f"python {platform.python_version()}, python-can {can.__version__}, best of {args.repeat}")
    print(
        f"{'loop':36s} {'frames':>9s} {'samples':>9s} {'time s':>8s} {'frames/s':>10s} {'samples/s':>10s} "
        f"{'vs bare':>8s}"
    )
    for name, t in best.items():
        frames, samples = counts[name]
        rate = f"{samples / t:10.0f}" if samples else f"{'-':>10s}"
        print(f"{name:36s} {frames:9d} {samples:9d} {t:8.2f} {frames / t:10.0f} {rate} {t / base - 1:+8.0%}")


if __name__ == "__main__":
    main()
