"""CAN frames to Samples: check, pair motor and load frames, unwrap, detect gaps.

One :class:`FramePipeline` is fed every frame seen live (from a Notifier) and, frame by frame,
in paced or strict replay; fast replay applies the same rules to blocks of frames
(:mod:`~online_backlash.codecs.blockpairing`, tested equal), so the same frames give the same
samples live and replayed.

Pairing (when motor and load come in two messages): by rolling counter when the messages have
one (a frame pairs with the pending frame of the other message with the same counter), else by
time (a frame pairs with the pending frame of the other message at most ``max_skew_s`` older).
A pending frame that is replaced before it finds its partner, or that is still waiting when a
newer pair completes, is counted ``unpaired`` (frames arrive in order, so it is an orphan). The time
of a sample is the earlier frame's; the skew (load frame time minus motor frame time) is
summarised in ``skew_mean_s`` and ``skew_max_s``.

A Sample's ``seq`` is the rolling counter of its frame(s) (None without counters).

Every frame ends in exactly one counter, so at the end (after :meth:`FramePipeline.flush`)::

    frames == skipped + corrupt + unpaired + frames_per_sample * samples

Both pipelines are :class:`CanPipeline`: blocks of frames in, a :class:`~online_backlash.stream.SampleChunk`
out (:meth:`CanPipeline.feed_frames`); :func:`~online_backlash.codecs.blockpairing.make_pipeline`
picks the block path where it applies.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import can

from online_backlash.errors import FrameError, InvalidParameterError
from online_backlash.stream import MAX_SKEW_S, Row, Sample, SampleChunk, StreamCounters, rows_to_chunk

from .dbc import BOTH, MOTOR, DecodedFrame
from .sample_checks import SampleAssembler
from .unwrap import Unwrapper


@dataclass
class CanCounters(StreamCounters):
    """:class:`~online_backlash.stream.StreamCounters` plus ``unpaired``: valid frames whose partner never came."""

    unpaired: int = 0

    def as_dict(self) -> dict[str, int]:
        out = StreamCounters.as_dict(self)
        out["unpaired"] = self.unpaired
        return out


class AngleScale(Protocol):
    """How a decoder's raw angle becomes degrees: where it rolls over (None: never) and the scale."""

    @property
    def modulus(self) -> int | None: ...

    def degrees(self, count: float, /) -> float: ...


class FrameDecoder(Protocol):
    """What :class:`FramePipeline` needs of a decoder: :class:`~online_backlash.codecs.dbc.DbcDecoder`
    (a DBC's messages) or :class:`~online_backlash.codecs.canopen.PdoDecoder` (event-driven CANopen TPDOs)."""

    @property
    def paired(self) -> bool: ...

    @property
    def counter_modulus(self) -> int | None: ...

    @property
    def motor(self) -> AngleScale: ...

    @property
    def load(self) -> AngleScale: ...

    def decode(self, msg: can.Message) -> DecodedFrame | None: ...


class CanPipeline(ABC):
    """What the per-frame and the block pipeline share: CAN frames in, samples and counters out.

    Attributes
    ----------
    counters : CanCounters
    frames_per_sample : int
        1 (one message carries both angles) or 2.
    skew_mean_s, skew_max_s : float
        Mean and largest absolute time between the frames of a pair, seconds (0 for one message).
    """

    def __init__(self, decoder: FrameDecoder, max_skew_s: float) -> None:
        if not max_skew_s >= 0:
            raise InvalidParameterError(f"max_skew_s must be >= 0, got {max_skew_s!r}")
        self.decoder = decoder
        self.max_skew_s = float(max_skew_s)
        self.counters = CanCounters()
        self.frames_per_sample = 2 if decoder.paired else 1

    def feed_frames(self, frames: Sequence[can.Message]) -> SampleChunk:
        """Count ``frames`` and decode them (:meth:`decode_frames`)."""
        self.counters.frames += len(frames)
        return self.decode_frames(frames)

    @abstractmethod
    def decode_frames(self, frames: Sequence[can.Message]) -> SampleChunk:
        """The samples these frames complete; the frames are already counted in ``counters.frames``
        (live, the notifier thread counts every frame as it arrives)."""

    @abstractmethod
    def flush(self) -> None:
        """End of stream: count the frames still waiting for a partner as unpaired."""

    @property
    @abstractmethod
    def skew_mean_s(self) -> float:
        """Mean absolute time between the frames of a pair, seconds."""

    @property
    @abstractmethod
    def skew_max_s(self) -> float:
        """Largest absolute time between the frames of a pair, seconds."""


class PerFramePipeline(CanPipeline):
    """A pipeline that decodes frame by frame (:meth:`_decode`): ``feed_row``, ``decode_frames``
    and the skew statistics, written once for the DBC pairing (:class:`FramePipeline`) and the
    CANopen SYNC grouping (:class:`~online_backlash.codecs.canopen.SyncPipeline`)."""

    _skew_mean_s = 0.0
    _skew_max_s = 0.0
    _n_skews = 0

    @abstractmethod
    def _decode(self, msg: can.Message) -> Row | None:
        """Decode one (already counted) frame; the sample it completes as a row, if any."""

    @property
    def skew_mean_s(self) -> float:
        return self._skew_mean_s

    @property
    def skew_max_s(self) -> float:
        return self._skew_max_s

    def _add_skew(self, skew_s: float) -> None:
        """Take the time between the frames of one completed sample (seconds) into the skew figures."""
        self._n_skews += 1
        self._skew_mean_s += (abs(skew_s) - self._skew_mean_s) / self._n_skews
        self._skew_max_s = max(self._skew_max_s, abs(skew_s))

    def feed_row(self, msg: can.Message) -> Row | None:
        """Count and decode one frame; the sample it completes as a row ``(time_s, motor_deg, load_deg,
        seq, after_gap)``, if any (no Sample object; :func:`~online_backlash.stream.rows_to_chunk`
        makes a block of rows)."""
        self.counters.frames += 1
        return self._decode(msg)

    def decode_frames(self, frames: Sequence[can.Message]) -> SampleChunk:
        decode = self._decode
        return rows_to_chunk([r for r in map(decode, frames) if r is not None])


class FramePipeline(PerFramePipeline):
    """Feed CAN messages, get Samples (degrees, multi-turn; seconds of the frame timestamps).

    Parameters
    ----------
    decoder : DbcDecoder or PdoDecoder
        Any :class:`FrameDecoder`: a DBC's messages, or event-driven CANopen TPDOs (no counter: paired by time).
    period_s : float, optional
        Nominal sample period (learnt from the first steps if None), for gap detection.
    max_skew_s : float
        Largest time between the two frames of a pair when pairing by time (no counters).
    strict : bool
        Raise :class:`~online_backlash.errors.FrameError` on a corrupt frame instead of counting it.

    Attributes
    ----------
    counters, frames_per_sample, skew_mean_s, skew_max_s
        See :class:`CanPipeline`.

    Examples
    --------
    >>> from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder, FrameEncoder
    >>> pipe = FramePipeline(DbcDecoder(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count"))
    >>> motor, load = FrameEncoder(pipe.decoder).frames(12.5, motor_count=4096, load_count=32768, counter=3)
    >>> pipe.feed(motor) is None  # waits for its partner
    True
    >>> pipe.feed(load)
    Sample(time_s=12.5, motor_deg=90.0, load_deg=90.0, torque_Nm=None, seq=3, after_gap=False)
    >>> pipe.counters.as_dict()
    {'frames': 2, 'samples': 1, 'corrupt': 0, 'skipped': 0, 'gaps': 0, 'unpaired': 0}
    """

    def __init__(
        self, decoder: FrameDecoder, period_s: float | None = None, max_skew_s: float = MAX_SKEW_S, strict: bool = False
    ) -> None:
        super().__init__(decoder, max_skew_s)
        self.strict = strict
        self._pending: list[DecodedFrame | None] = [None, None]  # [motor, load]
        self._assemble = SampleAssembler(self.counters, decoder.counter_modulus, period_s, strict).row
        self._motor_turns = Unwrapper(decoder.motor.modulus)
        self._load_turns = Unwrapper(decoder.load.modulus)
        self._motor_deg = decoder.motor.degrees
        self._load_deg = decoder.load.degrees

    def feed(self, msg: can.Message) -> Sample | None:
        """Account for one frame; return the Sample it completes, if any."""
        row = self.feed_row(msg)
        return None if row is None else Sample(row[0], row[1], row[2], None, row[3], row[4])

    def _decode(self, msg: can.Message) -> Row | None:
        """The sample ``msg`` completes, if any, as a row (the frame is counted by the caller)."""
        try:
            frame = self.decoder.decode(msg)
        except FrameError:
            if self.strict:
                raise
            self.counters.corrupt += 1
            return None
        if frame is None:
            self.counters.skipped += 1
            return None
        if frame.role == BOTH:
            return self._complete(frame.time_s, frame.counter, frame.motor_count, frame.load_count, 0.0)
        mine, other = (0, 1) if frame.role == MOTOR else (1, 0)
        partner = self._pending[other]
        if partner is not None and (
            frame.counter == partner.counter
            if frame.counter is not None
            else abs(frame.time_s - partner.time_s) <= self.max_skew_s
        ):
            self._pending[other] = None
            if self._pending[mine] is not None:  # an older frame whose partner never came
                self.counters.unpaired += 1
                self._pending[mine] = None
            motor, load = (frame, partner) if mine == 0 else (partner, frame)
            return self._complete(
                min(motor.time_s, load.time_s),
                frame.counter,
                motor.motor_count,
                load.load_count,
                load.time_s - motor.time_s,
            )
        if self._pending[mine] is not None:
            self.counters.unpaired += 1
        self._pending[mine] = frame
        return None

    def flush(self) -> None:
        """End of stream: count the frames still waiting for a partner as unpaired."""
        self.counters.unpaired += sum(p is not None for p in self._pending)
        self._pending = [None, None]

    def _complete(
        self, time_s: float, counter: int | None, motor_count: int, load_count: int, skew_s: float
    ) -> Row | None:
        if self.frames_per_sample == 2:
            self._add_skew(skew_s)
        return self._assemble(
            time_s,
            self._motor_deg(self._motor_turns(motor_count)),
            self._load_deg(self._load_turns(load_count)),
            counter,
            self.frames_per_sample,
        )
