"""Throughput of the recursive estimators beside other ways to run the same update.

Prints one markdown table, all rows measured in this run on the same rig-like data
(30:1, 1 kHz, 14-bit motor, 17-bit load, noise of 2 load counts, play 0.5 deg):

* ``BacklashRLS.learn_many`` (compiled), ``CascadeRLS.learn_many`` (n_a = n_b = 2, on the paper's
  example-3 system with a random input), ``BacklashRLS.learn_one`` (interpreted reference);
* the same 4-parameter RLS update of eq. (8)/(11) as a Python loop around filterpy's
  ``KalmanFilter.update`` (F = I, Q = 0, R = 1) and around padasip's ``FilterRLS.adapt``, with the
  switching functions eq. (12)-(13) evaluated from the current estimate as in ``learn_one``;
* the paper's batch algorithm (``VorosBacklash``) refitted on a sliding window;
* the limit: a bare compiled 4-parameter RLS update (covariance form) with no switching at all.

Then a second table on an input that reverses every few samples (a leaky random walk plus a slow
sine: about every 2 samples, the worst case for the switching and the reversal bookkeeping):
``BacklashRLS.learn_many`` and ``CascadeRLS.learn_many`` (n_a = n_b = 2) beside the bare compiled
4-parameter RLS loop with forgetting on the same input, in the same run, as a share of it, and beside
a bare loop of the cascade's own size (7 parameters, its regressor eq. 19 and target eq. 24 built
from the samples as they are: the limit for a 7-parameter covariance-form RLS).

Each row also prints the estimate the timed run reached (a loop that skips updates is not
fast, it is wrong). Then, with ``--csv-rows`` > 0, the end-to-end ``online-backlash estimate``
on a CSV log of that many rows (peak RSS and rows/s, CSV parsing included) beside
``pandas.read_csv`` and ``numpy.loadtxt`` of the same file, each in its own process.

Run: ``python bench/throughput.py`` (about 5 minutes on 2 cores, most of it writing and reading
the 10-million-row CSV once; the CSV is cached in ``--csv``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

import numpy as np
from numba import njit
from scipy.signal import lfilter

from online_backlash import BacklashRLS, CascadeRLS, VorosBacklash
from online_backlash.model import BacklashParams, simulate_backlash, simulate_cascade
from online_backlash.simulation.rig import simulate_rig

PLAY_DEG = 0.5
LOAD_COUNT_DEG = 360.0 / 2**17


class Timer:
    """Wall-clock and CPU (process) time of a block; on a shared machine the CPU time is what one core spends."""

    def __enter__(self) -> Timer:
        self.wall, self.cpu = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc: object) -> None:
        self.wall = time.perf_counter() - self.wall
        self.cpu = time.process_time() - self.cpu


def best_of(repeat: int, fn) -> Timer:
    """The run with the least CPU time out of ``repeat`` calls of ``fn``."""
    runs = []
    for _ in range(repeat):
        with Timer() as t:
            fn()
        runs.append(t)
    return min(runs, key=lambda r: r.cpu)


def timed(fn) -> tuple[Timer, object]:
    with Timer() as t:
        out = fn()
    return t, out


# -- the bare compiled update: the limit ------------------------------------------------------------
@njit(cache=True)
def bare_rls(u, y, side, lam):  # pragma: no cover - compiled
    """Covariance-form RLS, 4 parameters, regressor [u, 1, 0, 0] or [0, 0, u, -1] by ``side``; no switching.

    ``K = P phi / (lam + phi' P phi)``, ``theta += K e``, ``P = (P - K phi' P) / lam``, with one
    division per sample and the full 4x4 ``P`` (no use of the regressor's zeros).
    """
    theta = np.array([1.0, 0.0, 1.0, 0.0])
    P = np.eye(4) * 1e3
    phi = np.zeros(4)
    pphi = np.zeros(4)
    inv_lam = 1.0 / lam
    for t in range(u.shape[0]):
        if side[t]:
            phi[0] = 0.0
            phi[1] = 0.0
            phi[2] = u[t]
            phi[3] = -1.0
        else:
            phi[0] = u[t]
            phi[1] = 1.0
            phi[2] = 0.0
            phi[3] = 0.0
        s = lam
        e = y[t]
        for i in range(4):
            acc = 0.0
            for j in range(4):
                acc += P[i, j] * phi[j]
            pphi[i] = acc
            s += phi[i] * acc
            e -= theta[i] * phi[i]
        inv_s = 1.0 / s
        for i in range(4):
            k = pphi[i] * inv_s
            theta[i] += k * e
            for j in range(4):
                P[i, j] = (P[i, j] - k * pphi[j]) * inv_lam
    return theta


#: parameters of the cascade n_a = n_b = 2: [m1, c1, m2, c2] of eq. (20), a2, b1, b2
CASCADE_PARAMS = 7


@njit(cache=True)
def bare_rls_cascade(u, x, y, lam):  # pragma: no cover - compiled
    """Covariance-form RLS with the cascade's 7 parameters and its regressor, eq. (19) and target eq. (24)
    for n_a = n_b = 2, on the samples as they are: no switching functions of a model, no x_hat of eq. (23).

    ``phi(t) = [u(t-1) f1, f1, u(t-1) f2, -f2, x(t-2), -y(t-1), -y(t-2)]`` with ``f1``/``f2`` the direction
    of ``u`` at ``t-1`` (decreasing: left; increasing: right; every sample updates one side) and ``x`` the
    backlash output as given (measured, not estimated); target ``y(t) - x(t-1) (1 - f1) (1 - f2)``.
    ``K = P phi / (lam + phi' P phi)``, ``theta += K e``, ``P = (P - K phi' P) / lam``: one division per
    sample and the full 7x7 ``P`` (no use of its symmetry), the size fixed at compile time.
    """
    p = CASCADE_PARAMS
    theta = np.zeros(p)
    theta[0] = theta[2] = 1.0
    P = np.eye(p) * 1e3
    phi = np.zeros(p)
    pphi = np.zeros(p)
    inv_lam = 1.0 / lam
    for t in range(2, u.shape[0]):
        f2 = 1.0 if u[t - 1] > u[t - 2] else 0.0
        f1 = 1.0 - f2
        phi[0] = u[t - 1] * f1
        phi[1] = f1
        phi[2] = u[t - 1] * f2
        phi[3] = -f2
        phi[4] = x[t - 2]
        phi[5] = -y[t - 1]
        phi[6] = -y[t - 2]
        s = lam
        e = y[t] - x[t - 1] * (1.0 - f1) * (1.0 - f2)
        for i in range(p):
            acc = 0.0
            for j in range(p):
                acc += P[i, j] * phi[j]
            pphi[i] = acc
            s += phi[i] * acc
            e -= theta[i] * phi[i]
        inv_s = 1.0 / s
        for i in range(p):
            k = pphi[i] * inv_s
            theta[i] += k * e
            for j in range(p):
                P[i, j] = (P[i, j] - k * pphi[j]) * inv_lam
    return theta


def reversal_dense_input(n: int, seed: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Input that reverses every few samples, and the outputs of the two estimators' systems.

    ``u``: a leaky random walk (steps of 0.1 deg, pole 0.999: about 2.2 deg rms) plus a sine of
    2 deg at 0.1 Hz, 1 kHz; ``x``: backlash of play 0.5 deg (slopes 1) on it, plus noise of 0.01
    deg; ``y``: the same backlash followed by the linear block of the paper's example 3
    (``a2 = 0.5``, ``b = [-0.2, 0.35]``), plus the same noise. Degrees.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    u = lfilter([1.0], [1.0, -0.999], rng.normal(0.0, 0.1, n)) + 2.0 * np.sin(2 * np.pi * 0.1 * t)
    params = BacklashParams(1.0, 0.25, 1.0, 0.25)
    x = simulate_backlash(u, params) + rng.normal(0.0, 0.01, n)
    y = simulate_cascade(u, params, [0.5], [-0.2, 0.35])[0] + rng.normal(0.0, 0.01, n)
    return u, x, y


def reversal_dense_rows(n: int, repeat: int) -> list[tuple[str, int, Timer, str, int]]:
    """The bare loops and both estimators' ``learn_many`` on :func:`reversal_dense_input`, each
    started (warm start, compilation) on the first 20,000 samples and timed on the rest; each row ends with
    the number of parameters of the bare loop it is compared to (its own size)."""
    u, x, y = reversal_dense_input(n)
    warm = 20_000
    rows = []
    side = np.concatenate(([False], np.diff(u) > 0))
    bare_rls(u[:100], x[:100], side[:100], 1.0)
    t = best_of(repeat, lambda: bare_rls(u[warm:], x[warm:], side[warm:], 1.0 - 1e-4))
    reversals = int(np.sum(np.diff(side[warm:].astype(np.int8)) != 0))
    name = "bare compiled 4-parameter RLS loop (forgetting 1 - 1e-4, no switching)"
    rows.append((name, n - warm, t, f"({reversals:,} reversals of the input)", 4))
    bare_rls_cascade(u[:100], x[:100], y[:100], 1.0)
    t = best_of(repeat, lambda: bare_rls_cascade(u[warm:], x[warm:], y[warm:], 1.0 - 1e-4))
    rows.append((
        f"bare compiled {CASCADE_PARAMS}-parameter RLS loop, the cascade's regressor eq. (19) "
        "(forgetting 1 - 1e-4, no switching)",
        n - warm, t, "(the direction of u as switching, the measured x)", CASCADE_PARAMS,
    ))  # fmt: skip
    # memory_reversals=None: a memory counted in reversals would be a few dozen samples here
    for name, cls, out, size in (
        ("`BacklashRLS.learn_many`", BacklashRLS, x, 4),
        ("`CascadeRLS.learn_many` n_a = n_b = 2", CascadeRLS, y, CASCADE_PARAMS),
    ):
        est = cls(origin="zero", warm_start_samples=2000, memory_reversals=None)
        est.learn_many(u[:warm], out[:warm])
        state = est.state_dict()
        holder = {}

        def run(cls=cls, state=state, out=out, holder=holder):
            holder["est"] = fresh = cls.from_state(state)
            fresh.learn_many(u[warm:], out[warm:])

        t = best_of(repeat, run)
        e = holder["est"]
        th = e.theta_
        note = f"mL {th[0]:.4f} cL {th[1] / th[0]:.4f} mR {th[2]:.4f} cR {th[3] / th[2]:.4f} (truth 1 0.25 1 0.25)"
        rows.append((name, n - warm, t, note, size))
    return rows


# -- Python loops with third-party RLS updates ---------------------------------------------------
def switching_loop(u, y, theta0, update):
    """Eq. (12)-(13) from the current estimate, gated like learn_one, then ``update(phi, y) -> theta``.

    Returns the final ``theta`` and the number of updates.
    """
    theta = np.array(theta0, dtype=float)
    updates = 0
    for t in range(1, u.size):
        du = u[t] - u[t - 1]
        m1, c1, m2, c2 = theta
        phi = None
        if du < 0 and (m1 * u[t] + c1 - y[t - 1]) * m1 <= 0:  # eq. (12), left flank driven
            phi = np.array([u[t], 1.0, 0.0, 0.0])
        elif du > 0 and (y[t - 1] - m2 * u[t] + c2) * m2 <= 0:  # eq. (13), right flank driven
            phi = np.array([0.0, 0.0, u[t], -1.0])
        if phi is not None:
            theta = update(phi, y[t])
            updates += 1
    return theta, updates


def filterpy_loop(u, y, theta0):
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=4, dim_z=1)
    kf.x = np.array(theta0, dtype=float).reshape(4, 1)
    kf.P *= 1e3
    kf.R *= 1.0

    def update(phi, target):
        kf.update(np.array([[target]]), H=phi.reshape(1, 4))
        return kf.x.ravel()

    return switching_loop(u, y, theta0, update)


def padasip_loop(u, y, theta0):
    import padasip

    f = padasip.filters.FilterRLS(4, mu=1.0, eps=1e-3, w=np.array(theta0, dtype=float))

    def update(phi, target):
        f.adapt(target, phi)
        return f.w

    return switching_loop(u, y, theta0, update)


def theta_play(theta) -> float:
    return float(theta[1] / theta[0] + theta[3] / theta[2])


# -- the CSV part ---------------------------------------------------------------------------------
# peak RSS from VmHWM of /proc/self/status: the high-water mark of this process's own memory
# (getrusage's ru_maxrss would carry the parent's peak across fork + exec)
CHILD = """
import json, time
t = time.perf_counter()
{body}
seconds = time.perf_counter() - t
hwm = [line.split()[1] for line in open("/proc/self/status") if line.startswith("VmHWM:")][0]
print(json.dumps({{"seconds": seconds, "max_rss_mb": int(hwm) / 1024, "out": out}}))
"""

CSV_CASES = {
    "`online-backlash estimate LOG --ratio 30` (recursive, streamed)": (
        "import io, contextlib\nfrom online_backlash.cli import main\nbuf = io.StringIO()\n"
        "with contextlib.redirect_stdout(buf):\n    main(['estimate', {path!r}, '--ratio', '30', '--json'])\n"
        "out = json.loads(buf.getvalue())['backlash_deg']"
    ),
    "`CsvLog.iter_chunks()` alone (the reader of `estimate`)": (
        "from online_backlash.replay import CsvLog\nwith CsvLog({path!r}) as log:\n"
        "    out = sum(len(c) for c in log.iter_chunks())"
    ),
    "`pandas.read_csv` (whole file)": "import pandas\nout = len(pandas.read_csv({path!r}))",
    "`numpy.loadtxt` (whole file)": "import numpy\nout = len(numpy.loadtxt({path!r}, delimiter=',', skiprows=1))",
}


def ensure_csv(path: str, rows: int) -> None:
    if os.path.exists(path) and sum(1 for _ in open(path)) - 1 == rows:
        return
    rec = simulate_rig(duration_s=rows / 1000.0, play_deg=PLAY_DEG, seed=3)
    rec.write_csv(path)


def run_child(body: str) -> dict:
    """Run ``body`` (which sets ``out``) in a fresh interpreter; its time includes its imports."""
    done = subprocess.run([sys.executable, "-c", CHILD.format(body=body)], capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=5_000_000, help="samples for the compiled rows")
    ap.add_argument("--slow-samples", type=int, default=40_000, help="samples for the Python-loop rows")
    ap.add_argument("--csv-rows", type=int, default=10_000_000, help="rows of the CSV log (0: skip the CSV part)")
    ap.add_argument("--csv", default="/tmp/online_backlash_bench.csv", help="where to cache the CSV log")
    ap.add_argument("--repeat", type=int, default=3, help="timed repeats of the fast rows (best is reported)")
    args = ap.parse_args()

    n = args.samples
    rec = simulate_rig(duration_s=n / 1000.0, play_deg=PLAY_DEG, seed=1)
    u, y = rec.motor_deg / rec.ratio, rec.load_deg
    warm = 20_000  # samples learned before timing: the warm start (batch fit) and numba's compilation
    rows = []  # (name, samples, Timer, estimate reached)

    # BacklashRLS.learn_many
    started = BacklashRLS()
    started.learn_many(u[:warm], y[:warm])
    state = started.state_dict()
    holder = {}

    def run_many():
        holder["est"] = est = BacklashRLS.from_state(state)
        est.learn_many(u[warm:], y[warm:])

    t = best_of(args.repeat, run_many)
    est = holder["est"]
    rate_many = (n - warm) / t.cpu
    rows.append(
        (
            "`BacklashRLS.learn_many` (compiled)",
            n - warm,
            t,
            f"play {est.backlash_:.5f} deg (truth {PLAY_DEG}), {est.n_reversals_} reversals",
        )
    )

    # CascadeRLS.learn_many, example 3 of the paper with a random input, SNR 25
    rng = np.random.default_rng(2)
    uc = rng.uniform(-1, 1, n)
    yc, _ = simulate_cascade(uc, BacklashParams(1.3, 0.6, 2.0, 0.7), [0.5], [-0.2, 0.35])
    yc = yc + rng.normal(0, np.std(yc) / 25, n)
    cas = CascadeRLS(origin="zero", warm_start_samples=1500, memory_reversals=None)
    cas.learn_many(uc[:warm], yc[:warm])
    cstate = cas.state_dict()

    def run_cascade():
        holder["cas"] = est = CascadeRLS.from_state(cstate)
        est.learn_many(uc[warm:], yc[warm:])

    t = best_of(args.repeat, run_cascade)
    cas = holder["cas"]
    rate_cascade = (n - warm) / t.cpu
    rows.append((
        "`CascadeRLS.learn_many` n_a = n_b = 2 (compiled)", n - warm, t,
        f"mL {cas.m_left_:.3f} cL {cas.c_left_:.3f} mR {cas.m_right_:.3f} cR {cas.c_right_:.3f} "
        f"b {np.round(cas.b_, 3).tolist()}"
        " (truth 1.3 0.6 2.0 0.7 [-0.2, 0.35])",
    ))  # fmt: skip

    # bare compiled update (the limit)
    side = np.concatenate(([False], np.diff(u) > 0))
    uu, yy = u - u[0], y - y[0]
    bare_rls(uu[:100], yy[:100], side[:100], 1.0)
    t = best_of(args.repeat, lambda: bare_rls(uu, yy, side, 1.0 - 1e-4))
    rows.append(
        (
            "bare compiled 4-parameter RLS update, no switching (limit)",
            n,
            t,
            "(none: every sample updates the side given by the direction)",
        )
    )

    # interpreted and third-party loops on the first slow_samples after the warm start
    m = args.slow_samples
    su, sy = u[warm : warm + m], y[warm : warm + m]
    one = BacklashRLS.from_state(state)
    t, _ = timed(lambda: [one.learn_one(a, b) for a, b in zip(su.tolist(), sy.tolist())])
    rows.append(("`BacklashRLS.learn_one` (interpreted reference)", m, t, f"play {one.backlash_:.5f} deg"))

    # the loops below start from the same estimate, in the paper's coordinates from the slice's first sample
    m1, c1, m2, c2 = started.theta_
    du0, dy0 = su[0] - started.u_ref_, sy[0] - started.y_ref_
    theta0 = np.array([m1, c1 + m1 * du0 - dy0, m2, c2 - m2 * du0 + dy0])
    lu, ly = su - su[0], sy - sy[0]
    t, (th, k) = timed(lambda: filterpy_loop(lu, ly, theta0))
    rate_filterpy = m / t.cpu
    rows.append(
        (
            "Python loop + filterpy `KalmanFilter.update` (same RLS update)",
            m,
            t,
            f"play {theta_play(th):.5f} deg, {k:,} updates",
        )
    )
    t, (th, k) = timed(lambda: padasip_loop(lu, ly, theta0))
    rows.append(
        (
            "Python loop + padasip `FilterRLS.adapt` (same regressor)",
            m,
            t,
            f"play {theta_play(th):.5f} deg, {k:,} updates",
        )
    )

    # batch refit on a sliding window: 10 s window, refit every second of data
    window, hop, refits = 10_000, 1_000, 5
    fits = []

    def refit(k: int) -> None:
        lo = warm + k * hop
        fits.append(VorosBacklash(origin="first").fit(u[lo : lo + window], y[lo : lo + window]))

    t, _ = timed(lambda: [refit(k) for k in range(refits)])
    rows.append(
        (
            f"`VorosBacklash` refit on a sliding {window // 1000} s window every {hop // 1000} s",
            refits * hop,
            t,
            f"play {fits[-1].backlash_:.5f} deg",
        )
    )

    dense = reversal_dense_rows(n, args.repeat)

    load = os.getloadavg()
    print(
        f"# throughput ({platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; load "
        f"average {load[0]:.1f})\n"
    )
    print(f"command: `python bench/throughput.py --samples {n} --slow-samples {m} --csv-rows {args.csv_rows}`\n")
    print("samples/s from CPU time (one core's work); wall-clock beside it (the machine is shared)\n")
    print("| what | samples | CPU s | samples/s (CPU) | samples/s (wall) | estimate reached |")
    print("|---|---:|---:|---:|---:|---|")
    for name, count, tm, note in rows:
        print(f"| {name} | {count:,} | {tm.cpu:.3f} | {count / tm.cpu:,.0f} | {count / tm.wall:,.0f} | {note} |")
    print(
        f"\nlearn_many / filterpy loop: {rate_many / rate_filterpy:,.0f}x; cascade / filterpy loop: "
        f"{rate_cascade / rate_filterpy:,.0f}x"
    )
    print(f"a week at 1 kHz (604,800,000 samples) by learn_many: {604_800_000 / rate_many:.0f} s of CPU")

    bare_rates = {size: count / tm.cpu for _, count, tm, _, size in dense[:2]}
    print("\n## input reversing every few samples (leaky random walk + slow sine), same run\n")
    print(
        "| what | samples | CPU s | samples/s (CPU) | share of the bare 4-parameter loop "
        "| share of the bare loop of its size | estimate reached |"
    )
    print("|---|---:|---:|---:|---:|---:|---|")
    for name, count, tm, note, size in dense:
        rate = count / tm.cpu
        shares = f"{100 * rate / bare_rates[4]:.0f} % | {100 * rate / bare_rates[size]:.0f} %"
        print(f"| {name} | {count:,} | {tm.cpu:.3f} | {rate:,.0f} | {shares} | {note} |")

    if args.csv_rows > 0:
        ensure_csv(args.csv, args.csv_rows)
        size_mb = os.path.getsize(args.csv) / 1e6
        print(f"\n## CSV log of {args.csv_rows:,} rows ({size_mb:.0f} MB), each case in a fresh process\n")
        print("| what | seconds | rows/s | peak RSS (MB) | result |")
        print("|---|---:|---:|---:|---|")
        for name, body in CSV_CASES.items():
            res = run_child(body.format(path=args.csv))
            print(
                f"| {name} | {res['seconds']:.1f} | {args.csv_rows / res['seconds']:,.0f} | {res['max_rss_mb']:.0f} "
                f"| {res['out']} |"
            )
        print("\n(wall-clock seconds inside each process, imports included; peak RSS = VmHWM of that process)")


if __name__ == "__main__":
    main()
