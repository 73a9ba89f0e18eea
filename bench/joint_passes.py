"""The joint fit's compiled passes beside the array code they replaced, on a two-mass rig record.

For one point of the joint fit's search, the Gram matrix of ``[1, dx/dp, y - x]`` (``dx = d x / d [mL,
cL, mR, cR]``, eq. 1-3): before, ``backlash_sensitivity`` wrote ``x`` and ``dx``, ``dx`` was copied
into a block beside ``y - x`` and the block multiplied by itself; now ``joint._sensitivity_gram`` sums
it while it simulates. For the model view: the backlash directions (``play_sensitivity``) written out
from ``dx`` with ``numpy.column_stack``, against the compiled pass; and the last engaged sample
(``_switched``) from ``simulate_switching`` with ``numpy.maximum.accumulate``, against its compiled
pass. Each is checked to give the same numbers, then timed (best of 5 repeats of 10 calls).

Run: ``python bench/joint_passes.py`` (``--minutes 10``: the record's length).
"""

from __future__ import annotations

import argparse
import platform
import timeit

import numpy as np

from online_backlash.diagnostics.joint import _sensitivity_gram, _switched, play_sensitivity
from online_backlash.model import BacklashParams, backlash_sensitivity, simulate_switching
from online_backlash.simulation.two_mass_rig import simulate_two_mass


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="length of the 1 kHz record, minutes")
    args = parser.parse_args()
    rec = simulate_two_mass(duration_s=60.0 * args.minutes, motion="rig", coulomb_nm=0.05, seed=0)
    u, y = rec.motor_deg / 30.0, rec.load_deg - rec.load_deg[0]
    u = u - u[0]
    p = BacklashParams(1.0, 0.2, 1.0, 0.2)
    n = u.size
    a = np.empty((n, 5))
    whole = (np.zeros(1, np.int64), np.zeros(1, np.int64), np.full(1, n, np.int64), np.zeros(1))

    def gram_arrays() -> np.ndarray:
        x, dx = backlash_sensitivity(u, p)
        block = np.empty((n, 6))
        block[:, 0], block[:, 1:5] = 1.0, dx
        np.subtract(y, x, out=block[:, 5])
        return block.T @ block

    def gram_pass() -> np.ndarray:
        return _sensitivity_gram(u, y, p.m_left, p.c_left, p.m_right, p.c_right, *whole, a)

    def directions_arrays() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x, dx = backlash_sensitivity(u, p)
        d = np.column_stack((np.ones(n), dx[:, 0], dx[:, 2], 0.5 * (dx[:, 1] + dx[:, 3])))
        return d[:, 3], np.ascontiguousarray(d[:, :3]), x

    def switched_arrays() -> tuple[np.ndarray, np.ndarray]:
        x, f1, f2 = simulate_switching(u, p, 0.0)
        return x, np.maximum.accumulate(np.where((f1 + f2) > 0, np.arange(n), 0))

    np.testing.assert_allclose(gram_pass(), gram_arrays(), rtol=1e-10, atol=1e-10 * np.abs(gram_arrays()).max())
    assert all(np.array_equal(s, t) for s, t in zip(play_sensitivity(u, p), directions_arrays()))
    assert all(np.array_equal(s, t) for s, t in zip(_switched(u, p), switched_arrays()))

    print(f"machine: {platform.processor() or platform.machine()}, Python {platform.python_version()}, {n} samples\n")
    print("| what | arrays, ms | compiled pass, ms |")
    print("|---|---|---|")
    for what, old, new in (
        ("Gram matrix of [1, dx/dp, y - x] at one point", gram_arrays, gram_pass),
        ("backlash directions (play_sensitivity)", directions_arrays, lambda: play_sensitivity(u, p)),
        ("output and last engaged sample (_switched)", switched_arrays, lambda: _switched(u, p)),
    ):
        times = [min(timeit.repeat(f, number=10, repeat=5)) / 10 * 1e3 for f in (old, new)]
        print(f"| {what} | {times[0]:.2f} | {times[1]:.2f} |", flush=True)


if __name__ == "__main__":
    main()
