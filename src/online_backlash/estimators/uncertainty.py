"""The standard error of the play from its scatter over reversal cycles, not from sensor noise alone.

The least-squares standard error of eq. (14) (or of the output-error refinement) assumes white
output noise. On a real drive the play that each reversal shows scatters far more than that:
the load creeps onto the flank differently after each reversal (compliance, friction, a
position loop jumping the motor through the gap), the engaged flank is not exactly a straight
line (model misfit), and the noise is correlated over a cycle. Repeated runs then disagree by
10-30 times the white-noise standard error (issue 12). So the play is measured once per reversal
cycle, and the standard error of the estimate is the scatter of those per-cycle plays:

1. **Per-cycle plays** (:class:`~.reversal_plays.CyclePlays` in :mod:`.reversal_plays`). Every
   sample on an engaged flank implies where that flank is, its *flank offset*: on the left
   flank of eq. (1), ``y = mL (u + cL)``, so ``y / mL - u = cL``; on the right,
   ``y / mR - u = -cR`` (degrees, input units). A torque-aware model adds the wind-up,
   ``(y + tau / k) / m - u``. Consecutive samples on one flank form a *segment* (one half-cycle); the
   mean offset of each segment minus that of the adjacent segment on the other flank is one
   measurement of the play, one per reversal. Adjacent segments lie close together, so a slope error
   hardly enters their difference.
2. **Standard error of their mean** (:func:`play_std`): a moving-block bootstrap (Künsch 1989)
   of the (weighted) mean of the per-cycle plays, blocks of ``ceil(n^(1/3))`` consecutive plays
   (Hall, Horowitz & Jing 1995), so correlation between neighbouring cycles (each play shares a
   segment with the next; slow drifts) is kept. Reversal cycles act as the clusters of a
   cluster-robust standard error (Cameron & Miller 2015); with few clusters the bootstrap
   underestimates, so the result is scaled by ``sqrt(n / (n - 1))`` and by
   ``t_{0.975, n_eff - 1} / z_{0.975}``, the few-clusters correction of Cameron & Miller
   (sec. VI): then ``+-2`` standard errors is a 95 % interval even for 3 cycles. The result is
   never below ``floor_deg``, the white-noise standard error the estimator states.
3. **Recursive estimators** forget: with ``memory_reversals = M`` the estimate is close to a
   mean of the per-cycle plays weighted ``exp(-age / M)`` (:func:`forgetting_weights`), and its
   scatter is that of the weighted mean (Kish's effective number of cycles in step 2).
4. **Kinematic engagement** (:class:`~.reversal_plays.MotionFlanks`): without a torque signal, a
   sample is on a flank once the input has travelled more than the play (plus a margin) since its last
   reversal, on the left flank while ``u`` falls and the right while it rises (eq. 5-6 with the
   load at the far flank). A torque-aware estimator takes the flank from the torque sign instead.
5. **Model misfit**, which does not average away (a repeat run is driven a little differently,
   and a drive that is not the model gives a play that depends on how it was driven): the
   scatter between cycles beyond their white noise (``between_deg``, a variance component), or
   the fit's residual RMS beyond the output's own noise (:func:`model_misfit`, the noise from
   second differences, :class:`OutputNoise`), whichever is larger, is added in quadrature:
   ``std = sqrt(max(se, floor)^2 + max(between, misfit)^2)`` (:class:`PlayUncertainty`).

Measured on repeat runs (``bench/uncertainty.py``, ``docs/load-aware.md``): 91-100 % of run
pairs within two standard deviations of their difference on the rig, the two-mass rig and sine
runs at 0.3-0.7 Hz, where the white-noise standard error gave 0-98 %.

Units: degrees (input units, load side) throughout.

References
----------
H. R. Künsch, "The jackknife and the bootstrap for general stationary observations", Ann.
Statist. 17(3) (1989) 1217-1241. P. Hall, J. L. Horowitz, B.-Y. Jing, "On blocking rules for the
bootstrap with dependent data", Biometrika 82(3) (1995) 561-574. A. C. Cameron, D. L. Miller,
"A practitioner's guide to cluster-robust inference", J. Human Resources 50(2) (2015) 317-372.
L. Kish, *Survey Sampling*, Wiley 1965 (effective sample size). J. von Neumann, "Distribution of
the ratio of the mean square successive difference to the variance", Ann. Math. Statist. 12(4)
(1941) 367-395. J. Rice, "Bandwidth choice for nonparametric regression", Ann. Statist. 12(4)
(1984) 1215-1230 (difference-based noise variance).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from .full_engagement import NO_FLANK, FullEngagement
from .reversal_plays import CyclePlays, MotionFlanks, OutputNoise, kinematic_offsets, kinematic_update
from .snapshots import NOT_STARTED, EstimateAt
from .validation import finite_array

__all__ = [
    "CyclePlays",
    "EstimateAt",
    "KinematicPlayScatter",
    "MotionFlanks",
    "OutputNoise",
    "PlayUncertainty",
    "RecursivePlayScatter",
    "forgetting_weights",
    "kinematic_offsets",
    "model_misfit",
    "play_std",
    "play_uncertainty",
]

#: Samples :class:`RecursivePlayScatter` holds before its estimator starts.
MAX_HELD_SAMPLES = 4_000_000
#: Seconds of data between the ticks at which :class:`RecursivePlayScatter` measures (without a trace).
SCATTER_EVERY_S = 10.0
#: Bootstrap replicates of :func:`play_std`.
N_BOOT = 1000
_Z975 = 1.959963984540054


def forgetting_weights(n: int, memory_reversals: float | None) -> np.ndarray | None:
    """Weights ``exp(-age / memory_reversals)`` of ``n`` per-reversal plays (the newest has age 0);
    None (equal weights) when the estimator does not forget per reversal."""
    if memory_reversals is None:
        return None
    if not memory_reversals > 0:
        raise InvalidParameterError(f"memory_reversals must be > 0, got {memory_reversals}")
    return np.exp(-np.arange(n - 1, -1, -1, dtype=float) / float(memory_reversals))


@dataclass(frozen=True)
class PlayUncertainty:
    """The parts of the play's standard error, degrees.

    Attributes
    ----------
    std_deg : float
        What is reported as ``backlash_std_deg``:
        ``sqrt(max(se_deg, floor)^2 + max(between_deg, misfit_deg)^2)``.
    se_deg : float
        Standard error of the (weighted) mean of the per-cycle plays: moving-block bootstrap with
        the few-clusters corrections (NaN with fewer than 2 effective plays).
    between_deg : float
        The scatter between cycles beyond their white noise (model misfit: wind-up, creep,
        friction that differ with each cycle's motion): ``sqrt(max(0, var(plays) - mean noise
        variance))``, a variance component (one-way random effects). A repeat run moves
        differently (speed, amplitude, frequency), so this part is not averaged away.
    n_plays : int
        Per-cycle plays used.
    n_effective : float
        Kish's effective number of plays, ``(sum w)^2 / sum w^2``.
    misfit_deg : float
        The model misfit seen in the residual: ``sqrt(max(0, residual_rms^2 - noise^2))``
        (:func:`model_misfit`), with ``engagement_deg`` in quadrature; 0 where not given. It and
        ``between_deg`` measure one thing two ways (the drive is not the model: wind-up, creep): the
        larger counts.
    engagement_deg : float
        What the samples left out as partial crossings of the gap would take off the play, were they flank
        samples after all (:attr:`~.full_engagement.FullEngagement.shortfall_deg_`: without a torque column a
        partial crossing is not told apart from a wind-up that varies along the stroke); 0 where no sample was
        left out. Part of ``misfit_deg``.
    """

    std_deg: float
    se_deg: float
    between_deg: float
    n_plays: int
    n_effective: float
    misfit_deg: float = 0.0
    engagement_deg: float = 0.0


def play_uncertainty(
    plays_deg: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    noise_var_deg2: np.ndarray | None = None,
    floor_deg: float | None = None,
    misfit_deg: float = 0.0,
    block_len: int | None = None,
    n_boot: int = N_BOOT,
    seed: int = 0,
) -> PlayUncertainty:
    """The standard error of the play from per-cycle plays, degrees (see the module docstring).

    Parameters
    ----------
    plays_deg : array
        One play per reversal, in order (:attr:`CyclePlays.plays_deg`).
    weights : array, optional
        Weight of each play (e.g. :func:`forgetting_weights`); equal weights by default.
    noise_var_deg2 : array, optional
        White-noise variance of each play (:attr:`CyclePlays.noise_var_deg2`); 0 if not given
        (then all the scatter between cycles counts as misfit).
    floor_deg : float, optional
        The least the standard error of the mean may be: the white-noise standard error the
        estimator states. With fewer than 2 (effective) plays the result is this alone (NaN if
        not given).
    misfit_deg : float
        The model misfit of the fit's residual (:func:`model_misfit`), degrees.
    block_len : int, optional
        Moving-block length, default ``ceil(n^(1/3))`` (at most ``n // 2``).
    n_boot, seed : int
        Bootstrap replicates and the seed of their generator (the result is reproducible).
    """
    plays = finite_array("plays_deg", plays_deg)
    floor = math.nan if floor_deg is None else float(floor_deg)
    n = plays.size
    w = np.ones(n) if weights is None else finite_array("weights", weights)
    noise = np.zeros(n) if noise_var_deg2 is None else finite_array("noise_var_deg2", noise_var_deg2)
    if w.shape != plays.shape or np.any(w < 0) or noise.shape != plays.shape:
        raise InvalidParameterError(f"weights and noise_var_deg2 must be {n} non-negative values each")
    total = float(w.sum())
    n_eff = total**2 / float(np.sum(w * w)) if n and total > 0 else 0.0
    misfit = float(misfit_deg)
    if not (misfit >= 0 and math.isfinite(misfit)):
        raise InvalidParameterError(f"misfit_deg must be a finite angle >= 0, got {misfit_deg!r}")
    if n < 2 or n_eff < 2.0:
        return PlayUncertainty(math.hypot(floor, misfit), math.nan, math.nan, n, n_eff, misfit)
    b = max(1, min(n // 2, block_len if block_len is not None else math.ceil(n ** (1.0 / 3.0))))
    from scipy.special import stdtrit  # Student's t quantile; scipy.stats would cost 1 s and 50 MB more

    few = math.sqrt(n / (n - 1)) * float(stdtrit(n_eff - 1.0, 0.975)) / _Z975
    se = _block_bootstrap_sd(plays, w, b, n_boot, seed) * few
    mean = float(w @ plays) / total
    var = float(w @ (plays - mean) ** 2) / (total - float(w @ w) / total)  # reliability weights, unbiased
    between = math.sqrt(max(0.0, var - float(w @ noise) / total))
    se_floored = se if not se < floor else floor  # a NaN floor is no floor
    return PlayUncertainty(math.hypot(se_floored, max(between, misfit)), se, between, n, n_eff, misfit)


def play_std(plays_deg: np.ndarray, weights: np.ndarray | None = None, **options: Any) -> float:
    """:attr:`PlayUncertainty.std_deg` of :func:`play_uncertainty` (same arguments), degrees.

    Examples
    --------
    40 plays scattering 0.01 deg with no white noise: all of it is scatter between cycles
    (``between_deg``), and the mean's standard error (about ``0.01 / sqrt(40)``) adds a little.

    >>> rng = np.random.default_rng(3)
    >>> round(play_std(0.5 + 0.01 * rng.standard_normal(40)), 3)
    0.012
    """
    return play_uncertainty(plays_deg, weights, **options).std_deg


def model_misfit(residual_rms_deg: float, noise_var_deg2: float) -> float:
    """The part of a fit's residual RMS that white noise does not explain, degrees:
    ``sqrt(max(0, residual_rms^2 - noise variance))`` (0 when either is not finite)."""
    excess = float(residual_rms_deg) ** 2 - float(noise_var_deg2)
    return math.sqrt(excess) if math.isfinite(excess) and excess > 0 else 0.0


#: Resampled plays held at once by :func:`_block_bootstrap_sd` (its arrays stay near 2 MB each; the
#: draws, and so the result, do not depend on it)
BOOTSTRAP_BATCH = 250_000


def _block_bootstrap_sd(plays: np.ndarray, w: np.ndarray, block: int, n_boot: int, seed: int) -> float:
    """Standard deviation of the weighted mean over moving-block bootstrap resamples (Künsch 1989).

    Each resample lays ``ceil(n / block)`` blocks of ``block`` consecutive (play, weight) pairs,
    starts drawn uniformly, end to end and cut to ``n``.
    """
    n = plays.size
    rng = np.random.default_rng(seed)
    n_blocks = -(-n // block)
    offsets = np.arange(block)
    means = np.empty(n_boot)
    step = max(1, BOOTSTRAP_BATCH // max(n, 1))  # replicates per batch: bounded memory on long logs
    for lo in range(0, n_boot, step):
        hi = min(n_boot, lo + step)
        starts = rng.integers(0, n - block + 1, size=(hi - lo, n_blocks))
        idx = (starts[:, :, None] + offsets).reshape(hi - lo, -1)[:, :n]
        ww = w[idx]
        total = ww.sum(axis=1)
        means[lo:hi] = np.where(total > 0, (ww * plays[idx]).sum(axis=1) / np.where(total > 0, total, 1.0), np.nan)
    return float(np.nanstd(means, ddof=1))


class KinematicPlayScatter:
    """Per-reversal plays of a kinematic (no torque) drive, fed block by block: :class:`MotionFlanks`
    then :class:`CyclePlays` with the offsets of eq. (1) (:func:`kinematic_offsets`).

    The play and slopes that place the flanks come from the estimator (its current estimate:
    they may change from block to block).
    """

    def __init__(self) -> None:
        self.cycles = CyclePlays()
        self.noise = OutputNoise()
        self._flanks: MotionFlanks | None = None

    def update(
        self, u: np.ndarray, y: np.ndarray, gap: np.ndarray | None, play_deg: float, m_left: float, m_right: float,
        left_out: np.ndarray | None = None, level_deg: float = 0.0,
    ) -> None:  # fmt: skip
        """Add a block of input ``u`` and output ``y`` (degrees) with the current estimate (one
        compiled pass, :func:`~.reversal_plays.kinematic_update`); ``left_out``: samples on no flank
        (partial crossings of the gap, :class:`~.full_engagement.FullEngagement`); ``level_deg``: the output
        level the estimator reads its play at (the per-cycle plays are the flanks' distance there)."""
        if self._flanks is None:
            self._flanks = MotionFlanks.for_play(play_deg)
        else:  # follow the estimate (wear), keep the motion state
            self._flanks.follow(play_deg)
        kinematic_update(self._flanks, self.cycles, self.noise, u, y, gap, m_left, m_right, left_out, level_deg)

    @property
    def plays_deg(self) -> np.ndarray:
        """One play per reversal, degrees."""
        return self.cycles.plays_deg

    @property
    def noise_var_deg2(self) -> np.ndarray:
        """White-noise variance of each play, degrees squared."""
        return self.cycles.noise_var_deg2

    def uncertainty(
        self, floor_deg: float | None = None, memory_reversals: float | None = None, residual_rms_deg: float = math.nan,
        engagement_deg: float = 0.0,
    ) -> PlayUncertainty:  # fmt: skip
        """:func:`play_uncertainty` of the plays so far, weighted by :func:`forgetting_weights`, with
        the misfit of a fit whose residual RMS is ``residual_rms_deg`` against the output's noise, and in
        quadrature with it ``engagement_deg`` (:attr:`PlayUncertainty.engagement_deg`)."""
        plays = self.plays_deg
        misfit = math.hypot(model_misfit(residual_rms_deg, self.noise.var_deg2), engagement_deg)
        found = play_uncertainty(
            plays,
            forgetting_weights(plays.size, memory_reversals),
            noise_var_deg2=self.noise_var_deg2,
            floor_deg=floor_deg,
            misfit_deg=misfit,
        )
        return dataclasses.replace(found, engagement_deg=float(engagement_deg))


class RecursivePlayScatter:
    """The standard error of a recursive kinematic estimator's play, widened by the per-cycle scatter.

    Fed the blocks the estimator learned (after it learned them), it measures the play of every
    reversal with the estimator's play and slopes (:class:`KinematicPlayScatter`). So that the
    result does not depend on how the stream was cut into blocks, the samples are held until a
    data-clock tick (``due``: the pipeline's row instants, a fixed number of seconds of data apart)
    and measured with the estimate at that tick; :meth:`finish` measures the rest with the final
    estimate. Before the estimator starts at most :data:`MAX_HELD_SAMPLES` samples are held (more:
    the scatter is not measured, the estimator's own standard error is reported).
    :meth:`uncertainty` weighs the plays by the estimator's memory in reversals
    (:func:`forgetting_weights` of ``memory_reversals``; equal weights without it) and floors the
    result at the estimator's own ``backlash_std_``. An estimator that takes torque
    (``takes_torque``) states its own standard error: it is passed through unchanged.

    An estimator that fits its lines where the flanks are fully engaged (``full_engagement``, issue 27) is
    followed alike: the partial crossings are judged here as it judges them
    (:class:`~.full_engagement.FullEngagement`, the first samples measured as a whole record) and left out of
    the segments, and the per-cycle plays are read at the output level it reads its play at (the level of its
    first estimate measured, for the whole stream: a level moving from tick to tick would shift whole
    segments).

    Parameters
    ----------
    estimator : RecursiveEstimator
        Read through its public attributes: ``started``, ``backlash_``, ``backlash_std_``,
        ``m_left_``, ``m_right_``, ``memory_reversals``, ``takes_torque``.
    """

    def __init__(self, estimator: Any) -> None:
        self.estimator = estimator
        self.scatter = KinematicPlayScatter()
        # the partial crossings, judged as the estimator judges them (full_engagement)
        self._marks = FullEngagement() if getattr(estimator, "full_engagement", False) else None
        self._held: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]] = []
        self._n_held = 0
        self._given_up = False
        self._level_deg: float | None = None  # the output level the per-cycle plays are read at, once measured

    @property
    def _kinematic(self) -> bool:
        return not getattr(self.estimator, "takes_torque", False)

    def snapshot(self, due: bool = True) -> EstimateAt:
        """What :meth:`update` and :meth:`finish` read from the estimator, as it is now: hand it to
        them (``estimate=``) where they run later than the estimator learned (a worker thread).
        ``due`` False (for :meth:`update` of a block that ends between ticks): ``started`` alone, the
        play and slopes NaN (not read there; this saves reading them after every block)."""
        est = self.estimator
        if not due or not est.started:  # the play and slopes are not read before the start
            return EstimateAt(True, math.nan, math.nan, math.nan) if est.started else NOT_STARTED
        return est.estimate_now()

    def update(
        self,
        u: np.ndarray,
        y: np.ndarray,
        gap: np.ndarray | None = None,
        due: bool = True,
        estimate: EstimateAt | None = None,
    ) -> None:
        """Add a block the estimator has just learned: input ``u`` and output ``y`` (degrees, load
        side); ``due``: the block ends at a data-clock tick (measure what is held now, if the
        estimator has started and has a finite play; else hold it for the next tick).
        ``estimate``: the estimator as it was right after this block (:meth:`snapshot`; default: as it is now)."""
        if self._given_up or not self._kinematic:
            return
        self._held.append(
            (
                np.asarray(u, dtype=float),
                np.asarray(y, dtype=float),
                None if gap is None else np.asarray(gap, dtype=bool),
            )
        )
        self._n_held += len(u)
        at = estimate if estimate is not None else self.snapshot(due)
        if due:
            if at.started and math.isfinite(at.backlash_deg):
                self.finish(at)
        elif not at.started and self._n_held > MAX_HELD_SAMPLES:
            self._given_up, self._held, self._n_held = True, [], 0

    def update_ticks(
        self,
        u: np.ndarray,
        y: np.ndarray,
        gap: np.ndarray | None,
        ticks: Sequence[int],
        estimates: Sequence[EstimateAt],
        end: EstimateAt,
    ) -> None:
        """:meth:`update` of a block with data-clock ticks inside it: the samples up to each tick
        (``ticks``, counts of the block's samples, ascending) with the estimate there
        (``estimates``), the rest (ending between ticks) with ``end``, the estimate after the block
        (``started`` alone is read there): the same as cutting the block at its ticks."""
        lo = 0
        for tick, at in zip(ticks, estimates):
            self.update(u[lo:tick], y[lo:tick], None if gap is None else gap[lo:tick], due=True, estimate=at)
            lo = tick
        if lo < len(u):
            self.update(u[lo:], y[lo:], None if gap is None else gap[lo:], due=False, estimate=end)

    def finish(self, estimate: EstimateAt | None = None) -> None:
        """Measure the samples held with the estimator's estimate (at a tick, or at the end):
        ``estimate`` (:meth:`snapshot`), by default the current one."""
        at = estimate if estimate is not None else self.snapshot()
        if not self._held or not at.started:
            return
        held, self._held, self._n_held = self._held, [], 0
        if len(held) == 1:  # one block since the last tick (the usual case): no copy
            u, y, gap = held[0]
        else:
            u, y = (np.concatenate([h[k] for h in held]) for k in (0, 1))
            gap = np.concatenate([h[2] if h[2] is not None else np.zeros(len(h[0]), dtype=bool) for h in held])
        left_out = None
        if self._marks is not None:  # the first samples measured are judged as a whole record
            left_out = (self._marks.update if self._marks.settled_ else self._marks.fit)(u, y, gap) == NO_FLANK
        if self._level_deg is None:  # one level for the stream: a level moving between ticks would shift whole segments
            self._level_deg = at.level_deg
        self.scatter.update(u, y, gap, at.backlash_deg, at.m_left, at.m_right, left_out, self._level_deg)

    def uncertainty(self) -> PlayUncertainty:
        """The parts of :attr:`std_deg` (the estimator's own standard error alone for a torque estimator)."""
        own = float(self.estimator.backlash_std_)
        if not self._kinematic:
            return PlayUncertainty(own, math.nan, math.nan, 0, 0.0)
        est = self.estimator
        return self.scatter.uncertainty(own, getattr(est, "memory_reversals", None), float(est.residual_rms_))

    @property
    def std_deg(self) -> float:
        """Standard error of the estimator's play, degrees."""
        return self.uncertainty().std_deg
