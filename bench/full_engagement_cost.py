"""What the full-engagement judgement costs (issue 27's rule, ``estimators/full_engagement.py``), CPU seconds.

On the uncompressed Parquet file ``bench/end_to_end.py`` writes (10 M samples of the simulated 30:1 rig; run
that first), in one process and after a warm-up on the first 20,000 samples: ``FullEngagement.update`` over
the rest in blocks of 65,536 samples (the stream's judgement), then ``BacklashRLS.learn_many`` on the same
samples without and with ``full_engagement`` (the estimator ``estimate`` runs has it on). Two repetitions.

    python bench/full_engagement_cost.py [--file /tmp/online-backlash-e2e/rig-10000000-none.parquet]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pyarrow.parquet as pq

from online_backlash import BacklashRLS
from online_backlash.estimators.full_engagement import FullEngagement

WARM = 20_000
BLOCK = 65_536


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--file", default="/tmp/online-backlash-e2e/rig-10000000-none.parquet")
    ap.add_argument("--ratio", type=float, default=30.0)
    args = ap.parse_args()
    table = pq.read_table(args.file)
    u = np.ascontiguousarray(table.column("motor").to_numpy()) / args.ratio
    y = np.ascontiguousarray(table.column("load").to_numpy())
    print(f"{u.size} samples of {args.file}")
    print("| repetition | FullEngagement.update, CPU s | learn_many, CPU s | learn_many with full_engagement, CPU s |")
    print("|---|---:|---:|---:|")
    for rep in range(2):
        judge = FullEngagement()
        judge.update(u[:WARM], y[:WARM])
        start = time.process_time()
        for lo in range(WARM, u.size, BLOCK):
            judge.update(u[lo : lo + BLOCK], y[lo : lo + BLOCK])
        judged = time.process_time() - start
        cost = []
        for full_engagement in (False, True):
            est = BacklashRLS(full_engagement=full_engagement)
            est.learn_many(u[:WARM], y[:WARM])
            start = time.process_time()
            est.learn_many(u[WARM:], y[WARM:])
            cost.append(time.process_time() - start)
        print(f"| {rep + 1} | {judged:.2f} | {cost[0]:.2f} | {cost[1]:.2f} |")


if __name__ == "__main__":
    main()
