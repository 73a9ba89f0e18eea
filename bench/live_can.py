"""Live CAN at 4,000 frames/s: nothing lost, latency of the estimate, CPU of the listener.

A sender thread plays the simulated 30:1 rig onto python-can's ``virtual`` bus at 2 kHz with
motor and load in separate messages of the shipped ``rig.dbc`` (4,000 frames/s), stamping each
frame with its scheduled time (as a device with hardware timestamps would). The listener is what
``online-backlash listen can`` runs: :class:`~online_backlash.drivers.can.CanSource` (raw BLF log
first in the notifier thread) and ``fit_recursive`` over chunks of whatever has arrived
(``CanSource.iter_chunks``: the samples decoded in the notifier thread since the last receive,
as one block of arrays) in the main thread.

Reported: frames sent, frames counted by the source, frames read back from the raw log; the
latency from the moment the frame completing a sample was sent to the moment the estimate had
learnt that sample (p50/p99/max, over all samples and after the warm start); CPU time of the
process and of the sender thread, as a share of one core.

    python bench/live_can.py [--duration 60] [--rate 2000]
"""

from __future__ import annotations

import argparse
import platform
import sys
import tempfile
import threading
import time

import can
import numpy as np

from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.codecs.options import CanDecoding, FrameRules
from online_backlash.drivers.can import CanSource
from online_backlash.drivers.live import LiveOptions
from online_backlash.log_fit import fit_recursive
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.rig_logs import rig_can_frames

SIGNALS = ("MotorAngle.Count", "LoadAngle.Count")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of traffic")
    ap.add_argument("--rate", type=float, default=2000.0, help="samples per second (two frames each)")
    ap.add_argument(
        "--switch-interval", type=float, help="sys.setswitchinterval (GIL hand-over between threads), seconds"
    )
    args = ap.parse_args()
    if args.switch_interval:
        sys.setswitchinterval(args.switch_interval)

    rec = simulate_rig(duration_s=args.duration, rate_hz=args.rate, reversal_s=(1.0, 2.0), seed=0)
    frames = list(rig_can_frames(rec, DbcDecoder(RIG_DBC, *SIGNALS), start_s=0.0))
    n_samples = rec.time_s.size
    sent_at = np.zeros(n_samples)  # wall time the load frame (completing sample i) was sent
    sender_cpu = [0.0]
    raw_dir = tempfile.mkdtemp(prefix="live-can-")

    rx = can.Bus(interface="virtual", channel="bench")
    tx = can.Bus(interface="virtual", channel="bench", preserve_timestamps=True)
    source = CanSource(
        rx, CanDecoding(RIG_DBC, *SIGNALS), frames=FrameRules(1.0 / args.rate), live=LiveOptions(raw_dir)
    )

    def send() -> None:
        cpu0 = time.thread_time()
        start = time.time() + 0.2
        for i in range(n_samples):
            target = start + i / args.rate
            delay = target - time.time()
            if delay > 0:
                time.sleep(delay)
            motor, load = frames[2 * i], frames[2 * i + 1]
            motor.timestamp = load.timestamp = target
            tx.send(motor)
            tx.send(load)
            sent_at[i] = time.time()
        sender_cpu[0] = time.thread_time() - cpu0
        time.sleep(0.5)
        source.request_stop()

    learnt_at: list[float] = []

    def timed(chunks):
        for chunk in chunks:
            yield chunk
            learnt_at.extend([time.time()] * len(chunk))  # fit_recursive asks for the next chunk: this one is learnt

    sender = threading.Thread(target=send)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    sender.start()
    report, est = fit_recursive(
        timed(source.iter_chunks()), rec.ratio, memory_reversals=10.0, sample_period_s=1.0 / args.rate
    )
    sender.join()
    source.close()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    tx.shutdown()

    read_back = sum(1 for f in source.raw_log.files for _ in can.LogReader(f))
    latency_ms = (np.array(learnt_at[:n_samples]) - sent_at[: len(learnt_at)]) * 1e3
    warm = est.warm_start_.get("samples", 0) if isinstance(est.warm_start_, dict) else 0
    after = latency_ms[int(warm) + int(args.rate) :]  # one second after the warm start

    c = source.counters
    print(
        f"python {platform.python_version()}, python-can {can.__version__}; {args.duration:g} s at "
        f"{2 * args.rate:g} frames/s; "
        f"switch interval {sys.getswitchinterval() * 1e3:g} ms"
    )
    print(f"frames sent               {len(frames)}")
    print(
        f"frames counted by source  {c.frames}  (samples {c.samples}, corrupt {c.corrupt}, skipped {c.skipped}, "
        f"unpaired {c.unpaired}, gaps {c.gaps})"
    )
    print(f"frames in the raw log     {read_back}  ({len(source.raw_log.files)} file(s))")
    print(f"lost                      {len(frames) - read_back}")
    print(
        f"estimate                  {report.backlash_deg * 60:.3f} arcmin ± "
        f"{report.extra['backlash_std_deg'] * 60:.3f} (true {rec.play_deg[-1] * 60:.3f})"
    )
    for name, lat in (("all samples", latency_ms), ("after warm start + 1 s", after)):
        p50, p99, p999 = np.percentile(lat, [50, 99, 99.9])
        print(f"latency {name:24s} p50 {p50:7.3f} ms  p99 {p99:7.3f} ms  p99.9 {p999:7.3f} ms  max {lat.max():8.3f} ms")
    print(f"CPU process               {cpu / wall:6.1%} of one core ({cpu:.1f} s in {wall:.1f} s)")
    print(f"CPU sender thread         {sender_cpu[0] / wall:6.1%}")
    print(f"CPU listener (difference) {(cpu - sender_cpu[0]) / wall:6.1%}")


if __name__ == "__main__":
    main()
