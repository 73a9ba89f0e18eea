"""Blocked cross-validation folds over whole reversal cycles.

A term is only worth adding if it predicts the residual on data it was not fitted on. The
residual of a backlash fit is strongly autocorrelated, so a random split of samples would let
a term fit the very wiggle it is scored on from its neighbours. The folds below therefore hold
out *whole reversal cycles*: the record is cut where the direction of motion of the referred
motor angle ``u`` changes (a cycle is one movement up and the movement down after it, so both
flanks of the dead band are in every cycle), and cycle ``i`` goes to fold ``i mod k``. A record
with fewer than two cycles is cut into ``k`` contiguous blocks of time instead (said in
:attr:`Folds.kind`).

A long record is *screened*: the loop's detectors score their candidates on a subset of its
cycles (:meth:`Folds.screen`: groups of ``n_folds`` consecutive cycles, one of each fold, spread
evenly over the record, at least :data:`SCREEN_MIN_SAMPLES` samples; every :data:`SCREEN_STRIDE`-th
sample of them), and the candidates' joint refits run on every sample of those cycles: the screen
chooses which effect comes next. Everything it keeps (the configuration and the evidence of the
terms it adds, the settings walked in their fits, their joint fit, the held-out gains in the final
model) is computed on every sample.

Units: degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ._causal import motion_direction

#: folds of the cross-validation (at most; fewer when the record has fewer cycles)
N_FOLDS = 5
#: reversal cycles a screened record keeps at least (:meth:`Folds.screen`): two of every fold
SCREEN_CYCLES = 2 * N_FOLDS
#: a screen keeps at least this many samples, more cycles than asked for where cycles are short (a
#: 1 Hz reversal holds 1,000 samples at 1 kHz): on 15 cycles of a 60 s, 1 Hz two-mass log (15,000
#: samples, every second one scored) the dead band's motion, which acts near the reversals with 19
#: columns, held out at -0.61 where every cycle of the record held it at +0.5, and the screened loop
#: stopped a term short of the unscreened one (``tests/test_screen.py``). 100,000 samples are ten
#: cycles of the bench's two-mass rig (``bench/diagnose_speed.py``).
SCREEN_MIN_SAMPLES = 100_000
#: a record is screened only when it has at least this many times the cycles and the samples a screen keeps
#: (below, the confirmation on every sample costs about what the screen saves: on the synthetic
#: transmission-error logs of ``tests/test_screen.py`` the two break even at about 50 cycles)
SCREEN_FACTOR = 3
#: a screen's scores read every this-many-th sample of its cycles. Its scores only choose the
#: effect tried next: the one chosen is detected again, configured and evidenced on every sample
#: (``_search_round.confirmed_on_every_sample``). A first round's residual is smooth at the sampling rate
#: (lag-1 autocorrelation 0.990 on the 10-minute bench log, 0.990 at lag 2), so the screen's effective
#: sample size (``n (1 - rho) / (1 + rho)``, :mod:`._scoring`, ``rho`` then between samples
#: ``stride`` apart) hardly changes; later residuals are nearer the noise (0.32 and 0.28 after the
#: compliance there), where it about halves. On the 10- and 60-minute bench logs the loop chooses,
#: configures and fits the same terms with 2 as with 1, to the last bit (``docs/benchmarks.md``).
SCREEN_STRIDE = 2
#: the direction of motion: sign of the change of ``u`` over this many samples, held inside
#: a change of ``DEADZONE_DEG`` (as for the per-flank generic term)
DIRECTION_WINDOW = 10
DEADZONE_DEG = 0.005


@dataclass(frozen=True)
class Folds:
    """Fold number of every sample, and how the folds were made.

    Attributes
    ----------
    fold : array of int
        Fold of each sample, ``0 .. n_folds - 1``.
    n_folds : int
    n_cycles : int
        Reversal cycles found in the record.
    kind : str
        ``"reversal cycles"`` or ``"time blocks"`` (fewer than two cycles).
    """

    fold: np.ndarray
    n_folds: int
    n_cycles: int
    kind: str
    #: the runs (positions in the record's runs, :attr:`segments`) a screen keeps; None: all of them
    kept: tuple[int, ...] | None = None
    #: a screen's scores read every ``stride``-th sample of its cycles (:attr:`row_index`; :meth:`screen`)
    stride: int = 1

    @cached_property
    def _runs(self) -> list[tuple[int, int, int]]:
        cuts = np.flatnonzero(np.diff(self.fold)) + 1
        starts = np.concatenate(([0], cuts))
        stops = np.concatenate((cuts, [self.fold.size]))
        return [(int(self.fold[a]), int(a), int(b)) for a, b in zip(starts, stops)] if self.fold.size else []

    @cached_property
    def segments(self) -> list[tuple[int, int, int]]:
        """The record (or the screen's cycles) as contiguous runs of one fold: ``(fold, start, stop)``
        sample ranges, in order."""
        return self._runs if self.kept is None else [self._runs[i] for i in self.kept]

    @property
    def screened(self) -> bool:
        """True when only some of the record's samples are used (:meth:`screen`)."""
        return self.kept is not None

    @cached_property
    def rows(self) -> int:
        """Samples in :attr:`row_index`."""
        return self.fold.size if self.kept is None else sum(len(range(a, b, self.stride)) for _, a, b in self.segments)

    @cached_property
    def compact_segments(self) -> list[tuple[int, int, int]]:
        """:attr:`segments` as positions in :attr:`row_index` (the screen's samples side by side),
        ``(fold, start, stop)``."""
        out, at = [], 0
        for k, a, b in self.segments:
            m = len(range(a, b, self.stride))
            out.append((k, at, at + m))
            at += m
        return out

    @cached_property
    def row_index(self) -> np.ndarray:
        """The indices of the samples the scores read: in :attr:`segments`, in order, every :attr:`stride`-th
        from each one's start."""
        return (
            np.concatenate([np.arange(a, b, self.stride) for _, a, b in self.segments])
            if self.segments
            else np.zeros(0, np.int64)
        )

    @cached_property
    def cycle_rows(self) -> np.ndarray:
        """Every sample of :attr:`segments`, in order (:attr:`row_index` without the stride: the rows the
        candidates' joint refits run over, runs of consecutive samples)."""
        return (
            np.concatenate([np.arange(a, b) for _, a, b in self.segments]) if self.segments else np.zeros(0, np.int64)
        )

    def screen(
        self,
        cycles: int = SCREEN_CYCLES,
        factor: int = SCREEN_FACTOR,
        stride: int = SCREEN_STRIDE,
        min_samples: int | None = None,
    ) -> Folds:
        """These folds restricted to about ``cycles`` whole reversal cycles spread evenly over the
        record (more where its cycles are short: as many as hold about ``min_samples`` samples at the
        record's mean cycle length): groups of ``n_folds`` consecutive cycles (one of each fold), as
        many groups as that asks, the first and the last group of the record among them; the scores
        read every ``stride``-th sample of them (:attr:`row_index`), the joint refits every one
        (:attr:`cycle_rows`). The record itself (``self``) when it has fewer than ``factor`` times those
        cycles, or is cut into time blocks. ``min_samples``: :data:`SCREEN_MIN_SAMPLES` if None."""
        runs = self._runs
        k = self.n_folds
        min_samples = SCREEN_MIN_SAMPLES if min_samples is None else min_samples
        for_samples = math.ceil(
            min_samples * self.n_cycles / max(self.fold.size, 1)
        )  # cycles of mean length holding min_samples
        if (
            self.kind != "reversal cycles"
            or self.n_cycles < factor * max(cycles, for_samples)
            or len(runs) != self.n_cycles
            or k < 2
        ):
            return self
        groups = self.n_cycles // k
        wanted = max(cycles // k, -(-for_samples // k), 2)
        if wanted >= groups:  # it would keep (nearly) every cycle
            return self
        chosen = np.unique(np.round(np.linspace(0, groups - 1, wanted)).astype(int))
        return Folds(
            self.fold, k, self.n_cycles, self.kind, tuple(int(g * k + j) for g in chosen for j in range(k)), stride
        )

    def as_dict(self) -> dict[str, object]:
        """For the JSON evidence: ``{"folds", "cycles", "split"}``."""
        return {"folds": self.n_folds, "cycles": self.n_cycles, "split": self.kind}


def reversal_cycles(u_deg: np.ndarray) -> np.ndarray:
    """Cycle number of every sample: it grows by one at every second reversal of the motion of ``u_deg``."""
    d = motion_direction(np.asarray(u_deg, dtype=float), DIRECTION_WINDOW, DEADZONE_DEG, 0.0)
    changes = np.concatenate(([0], np.cumsum(d[1:] * d[:-1] < 0)))  # reversals so far
    return changes // 2


def cycle_folds(u_deg: np.ndarray, n_folds: int = N_FOLDS) -> Folds:
    """:class:`Folds` of whole reversal cycles (interleaved), or of time blocks for a record of fewer than 2 cycles."""
    u = np.asarray(u_deg, dtype=float)
    cycle = reversal_cycles(u)
    n_cycles = int(cycle[-1]) + 1 if cycle.size else 0
    if n_cycles >= 2:
        k = min(n_folds, n_cycles)
        return Folds(cycle % k, k, n_cycles, "reversal cycles")
    k = max(2, n_folds)
    return Folds(np.minimum(np.arange(u.size) * k // max(u.size, 1), k - 1), k, n_cycles, "time blocks")
