"""The rules of :class:`~online_backlash.codecs.pairing.FramePipeline` on decoded blocks of frames, compiled.

Frames come in blocks (1,024 frames read from a log) and are decoded into arrays
(:mod:`~online_backlash.codecs.blockdecode`); this module
pairs them, unwraps the counts (:class:`~online_backlash.codecs.unwrap.Unwrapper`), applies
:class:`~online_backlash.codecs.sample_checks.SampleAssembler`'s checks and
:class:`~online_backlash.codecs.gaps.GapDetector`'s rule in one numba loop whose state carries
over from block to block, so the samples, counters, gaps and pair skew are those of the per-frame
path, bit for bit (``tests/test_can_blocks.py`` compares them over generated damaged inputs).
Strict decoding (raise at the corrupt frame), paced replay and DBCs the block decoder does not
support take the per-frame path (:func:`make_pipeline` chooses).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import can
import numpy as np
from numba import njit

from online_backlash.errors import InvalidParameterError
from online_backlash.stream import MAX_SKEW_S, Gap, SampleChunk

from .blockdecode import CORRUPT, OK, SKIPPED, BlockDecoder, DecodedBlock, frame_arrays
from .dbc import BOTH, MOTOR, DbcDecoder
from .gaps import CounterClock, GapDetector
from .pairing import CanPipeline, FramePipeline

# integer state: pending frame [motor, load] (has, counter, count); unwrapper [motor, load] (has, last, total);
# gap detector (has last, last counter, steps learnt, period known); pairs counted
_P_HAS, _P_COUNTER, _P_COUNT = 0, 2, 4
_U_HAS, _U_LAST, _U_TOTAL = 6, 8, 10
_G_HAS, _G_COUNTER, _G_STEPS, _G_KNOWN, _N_PAIRS = 12, 13, 14, 15, 16
_N_INT = 17
# float state: pending frame time [motor, load]; assembler's last time; gap detector's last time and period; skew
_P_TIME, _A_LAST, _G_LAST, _G_PERIOD, _SKEW_MEAN, _SKEW_MAX = 0, 2, 3, 4, 5, 6
_N_FLOAT = 7


@njit(cache=True)
def _unwrap(ist, k, count, modulus):  # pragma: no cover - compiled
    """Unwrapper.__call__ for encoder k (0 motor, 1 load); modulus 0: multi-turn, unchanged (Unwrapper(None))."""
    if ist[_U_HAS + k] == 0 or modulus == 0:
        ist[_U_HAS + k] = 1
        ist[_U_TOTAL + k] = count
    else:
        step = ((count - ist[_U_LAST + k]) % modulus + modulus) % modulus
        if step > modulus // 2:
            step -= modulus
        ist[_U_TOTAL + k] += step
    ist[_U_LAST + k] = count
    return ist[_U_TOTAL + k]


@njit(cache=True)
def _median(values):  # pragma: no cover - compiled
    """statistics.median."""
    s = np.sort(values)
    n = s.size
    if n % 2 == 1:
        return s[n // 2]
    return (s[n // 2 - 1] + s[n // 2]) / 2


@njit(cache=True)
def _pair_block(
    status,
    role,
    counter,
    motor,
    load,
    time_s,
    paired,
    max_skew_s,
    motor_cpr,
    load_cpr,
    motor_scale,
    load_scale,
    motor_offset,
    load_offset,
    modulus,
    gap_periods,
    ist,
    fst,
    steps,
    out_time,
    out_motor,
    out_load,
    out_seq,
    out_gap,
    gap_time,
    gap_dt,
    gap_missing,
):  # pragma: no cover - compiled
    """Process one block; returns (samples, gaps, corrupt, unpaired) added by it."""
    n_samples = 0
    n_gaps = 0
    corrupt = 0
    unpaired = 0
    frames_per_sample = 2 if paired else 1
    learn_steps = steps.size
    for i in range(status.size):
        if status[i] != OK:
            continue
        t = time_s[i]
        c = counter[i]
        skew = 0.0
        if role[i] == BOTH:
            motor_count, load_count, sample_t = motor[i], load[i], t
        else:
            mine = 0 if role[i] == MOTOR else 1
            other = 1 - mine
            match = False
            if ist[_P_HAS + other] == 1:
                if c >= 0:
                    match = c == ist[_P_COUNTER + other]
                else:
                    match = abs(t - fst[_P_TIME + other]) <= max_skew_s
            if not match:
                if ist[_P_HAS + mine] == 1:
                    unpaired += 1
                ist[_P_HAS + mine] = 1
                ist[_P_COUNTER + mine] = c
                ist[_P_COUNT + mine] = motor[i] if mine == 0 else load[i]
                fst[_P_TIME + mine] = t
                continue
            ist[_P_HAS + other] = 0
            if ist[_P_HAS + mine] == 1:
                unpaired += 1
                ist[_P_HAS + mine] = 0
            if mine == 0:
                motor_t, load_t, motor_count, load_count = t, fst[_P_TIME + 1], motor[i], ist[_P_COUNT + 1]
            else:
                motor_t, load_t, motor_count, load_count = fst[_P_TIME], t, ist[_P_COUNT], load[i]
            sample_t = load_t if load_t < motor_t else motor_t  # min(motor, load) as Python does it
            skew = load_t - motor_t
        if paired:
            ist[_N_PAIRS] += 1
            fst[_SKEW_MEAN] += (abs(skew) - fst[_SKEW_MEAN]) / ist[_N_PAIRS]
            if abs(skew) > fst[_SKEW_MAX]:
                fst[_SKEW_MAX] = abs(skew)
        motor_deg = _unwrap(ist, 0, motor_count, motor_cpr) * motor_scale + motor_offset  # EncoderSignal.degrees
        load_deg = _unwrap(ist, 1, load_count, load_cpr) * load_scale + load_offset
        # SampleAssembler.make
        if not (np.isfinite(sample_t) and np.isfinite(motor_deg) and np.isfinite(load_deg)):
            corrupt += frames_per_sample
            continue
        if sample_t < fst[_A_LAST]:
            corrupt += frames_per_sample
            continue
        fst[_A_LAST] = sample_t
        # GapDetector.check
        gap = False
        if ist[_G_HAS] == 0:
            ist[_G_HAS] = 1
        else:
            dt = sample_t - fst[_G_LAST]
            last_c = ist[_G_COUNTER]
            missing = 0
            if modulus > 0 and c >= 0 and last_c >= 0:
                missing = ((c - last_c - 1) % modulus + modulus) % modulus
            if ist[_G_KNOWN] == 0:
                if missing == 0:
                    steps[ist[_G_STEPS]] = dt
                    ist[_G_STEPS] += 1
                    if ist[_G_STEPS] == learn_steps:
                        median = _median(steps) if modulus == 0 else np.mean(steps)  # GapDetector._learn
                        if median > 0:
                            fst[_G_PERIOD] = median
                            ist[_G_KNOWN] = 1
                        ist[_G_STEPS] = 0
                else:
                    gap = True
            elif missing != 0 or dt > gap_periods * fst[_G_PERIOD]:
                gap = True
                missing = max(missing, int(np.rint(dt / fst[_G_PERIOD])) - 1)
            if gap:
                gap_time[n_gaps] = sample_t
                gap_dt[n_gaps] = dt
                gap_missing[n_gaps] = missing
                n_gaps += 1
        fst[_G_LAST] = sample_t
        ist[_G_COUNTER] = c
        out_time[n_samples] = sample_t
        out_motor[n_samples] = motor_deg
        out_load[n_samples] = load_deg
        out_seq[n_samples] = c
        out_gap[n_samples] = gap
        n_samples += 1
    return n_samples, n_gaps, corrupt, unpaired


class BlockPipeline(CanPipeline):
    """:class:`~online_backlash.codecs.pairing.FramePipeline` (non-strict) for blocks of frames.

    The frames are checked and decoded by :class:`~online_backlash.codecs.blockdecode.BlockDecoder`
    (arrays, vectorised) and paired, unwrapped, checked and gap-tested by one compiled loop.

    Parameters
    ----------
    decoder : DbcDecoder
        Must be one :attr:`BlockDecoder.supported <online_backlash.codecs.blockdecode.BlockDecoder.supported>`
        handles (see :func:`make_pipeline`).
    period_s, max_skew_s
        As for FramePipeline.

    Attributes
    ----------
    counters : CanCounters
    frames_per_sample : int
    skew_mean_s, skew_max_s : float
    """

    decoder: DbcDecoder  # the block path reads the DBC's scaling (a narrower FrameDecoder)

    def __init__(self, decoder: DbcDecoder, period_s: float | None = None, max_skew_s: float = MAX_SKEW_S) -> None:
        super().__init__(decoder, max_skew_s)
        gaps = GapDetector(decoder.counter_modulus, period_s)  # validates, and holds the rule's settings
        self.blocks = BlockDecoder(decoder)
        if not self.blocks.supported:
            raise InvalidParameterError(
                "this DBC needs the per-frame path (a message over 8 bytes, multiplexed, or a float signal)"
            )
        self._modulus = gaps.counter_modulus or 0
        self._gap_periods = gaps.gap_periods
        self._ist = np.zeros(_N_INT, dtype=np.int64)
        self._fst = np.zeros(_N_FLOAT, dtype=np.float64)
        self._fst[_A_LAST] = -math.inf
        if gaps.period_s is not None:
            self._fst[_G_PERIOD] = gaps.period_s
            self._ist[_G_KNOWN] = 1
        self._steps = np.zeros(gaps.learn_steps, dtype=np.float64)
        self._clock = (
            CounterClock(self._modulus, period_s) if self._modulus and period_s is not None else None
        )  # as SampleAssembler

    @property
    def skew_mean_s(self) -> float:
        return float(self._fst[_SKEW_MEAN])

    @property
    def skew_max_s(self) -> float:
        return float(self._fst[_SKEW_MAX])

    def decode_frames(self, frames: Sequence[can.Message]) -> SampleChunk:
        time_s, arrays = frame_arrays(frames)
        return self.decode_block(self.blocks.decode(*arrays), time_s)

    def decode_block(self, block: DecodedBlock, time_s: np.ndarray) -> SampleChunk:
        """The samples completed by a decoded block (frame times in seconds): counts ``corrupt``
        and ``skipped`` frames, then pairs, unwraps, checks and finds gaps."""
        c = self.counters
        c.corrupt += int(np.count_nonzero(block.status == CORRUPT))
        c.skipped += int(np.count_nonzero(block.status == SKIPPED))
        n = time_s.shape[0]
        out = (np.empty(n), np.empty(n), np.empty(n), np.empty(n, dtype=np.int64), np.empty(n, dtype=np.bool_))
        gaps = (np.empty(n), np.empty(n), np.empty(n, dtype=np.int64))
        dec = self.decoder
        n_samples, n_gaps, corrupt, unpaired = _pair_block(
            block.status, block.role, block.counter, block.motor, block.load, time_s,
            dec.paired, self.max_skew_s, dec.motor.modulus or 0, dec.load.modulus or 0,
            dec.motor.deg_per_raw, dec.load.deg_per_raw, dec.motor.offset_deg, dec.load.offset_deg,
            self._modulus, self._gap_periods,
            self._ist, self._fst, self._steps, *out, *gaps,
        )  # fmt: skip
        c.samples += n_samples
        c.corrupt += corrupt
        c.unpaired += unpaired
        for t, dt, missing in zip(*(g[:n_gaps].tolist() for g in gaps)):
            c.report_gap(Gap(t, dt, missing))
        time, motor, load, seq, after_gap = (a[:n_samples] for a in out)
        if self._clock is not None:
            time = self._clock.times(time, seq)
        return SampleChunk(time, motor, load, np.full(n_samples, np.nan), after_gap, seq=seq)

    def flush(self) -> None:
        self.counters.unpaired += int(self._ist[_P_HAS] + self._ist[_P_HAS + 1])
        self._ist[_P_HAS : _P_HAS + 2] = 0


def make_pipeline(
    decoder: DbcDecoder,
    period_s: float | None = None,
    max_skew_s: float = MAX_SKEW_S,
    strict: bool = False,
    per_frame: bool = False,
) -> FramePipeline | BlockPipeline:
    """The block pipeline where it applies, else the per-frame one (``strict``, ``per_frame``, or a
    DBC the block decoder does not support); both give the same samples and counters."""
    if strict or per_frame or not BlockDecoder(decoder).supported:
        return FramePipeline(decoder, period_s, max_skew_s, strict)
    return BlockPipeline(decoder, period_s, max_skew_s)
