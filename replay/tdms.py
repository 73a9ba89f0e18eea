"""NI TDMS files (LabVIEW rigs) as a sample source.

Channels are named ``group/channel`` (``columns={"motor": "Encoders/Motor", "load":
"Encoders/Load"}``); a bare channel name is accepted when one group holds it. Time comes from the
motor channel's waveform properties (``wf_start_offset + i * wf_increment``, seconds) or from
a channel mapped to ``time``. A channel of another length or rate is interpolated linearly onto
the motor's time base from its own waveform time (motor samples outside its span are counted in
``counters.skipped``). The ``unit_string`` property decides each channel's unit as in
:func:`~online_backlash.replay.tabular.channel_scales` (no property: degrees, seconds, N m);
``units=`` overrides the angles' units. The motor channel's ``wf_start_time`` (UTC, as TDMS
stores it) is the file's own clock of its waveform time
(:attr:`~online_backlash.stream.SampleSource.time_origin_unix_s`).

The file is opened with ``TdmsFile.open`` (streaming) and read in slices of ``block_rows``, so
memory stays flat. A file npTDMS cannot read raises :class:`~online_backlash.errors.LogFormatError`
naming the file and the channel. A file cut short (a recorder stopped mid-segment, a copy cut in
half) is read by npTDMS up to the cut with only a log line as a sign: that is taken as the sign
(:func:`_open_tdms`), and the file is refused as truncated, or with ``skip_bad`` read up to the cut
with the cut counted as one corrupt frame.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
import os
from collections.abc import Iterator
from typing import IO, Any

import numpy as np

from online_backlash.errors import LogFormatError
from online_backlash.stream import UNIX_TIME_MIN, SampleChunk, StreamCounters

from . import tabular
from .formats import CHANNELS, TABULAR, LogFormat
from .summary import FileSummary
from .tabular import ROLES, ChannelInfo, MeasurementLog, Resampler, channel_scales, missing_channel, open_with

#: What npTDMS logs when the file ends inside a segment (its only sign of a file cut short).
_CUT_SHORT = ("Last segment", "not a multiple of the chunk size")


def _open_tdms(path: str) -> tuple[Any, IO[bytes], bool]:
    """npTDMS's streaming reader over a file object this module closes (npTDMS leaves it open when it fails),
    and whether the file is cut short (npTDMS said so in its log, which is kept off the console here)."""
    from nptdms import TdmsFile  # imported on use

    with _nptdms_log() as said:
        tdms, stream = open_with(path, "TDMS", TdmsFile.open)
    return tdms, stream, any(sign in line for line in said for sign in _CUT_SHORT)


@contextlib.contextmanager
def _nptdms_log() -> Iterator[list[str]]:
    """The lines npTDMS's loggers (``nptdms.*``, each with its own console handler) log meanwhile, kept
    instead of printed."""
    said: list[str] = []

    def keep(record: logging.LogRecord) -> bool:
        said.append(record.getMessage())
        return False

    loggers = [logging.getLogger(name) for name in list(logging.root.manager.loggerDict) if name.startswith("nptdms.")]
    for logger in loggers:
        logger.addFilter(keep)
    try:
        yield said
    finally:
        for logger in loggers:
            logger.removeFilter(keep)


def _cut_short(channels: dict[str, Any]) -> str:
    """The reason of a TDMS file cut short, with what npTDMS can read of each channel."""
    lengths = ", ".join(f"{name} {len(channel)}" for name, channel in channels.items())
    return f"truncated: the file ends inside its last segment (readable values: {lengths})"


def _channels(tdms: Any) -> dict[str, Any]:
    """``group/channel`` -> channel, in file order."""
    return {f"{group.name}/{channel.name}": channel for group in tdms.groups() for channel in group.channels()}


class TdmsLog(MeasurementLog):
    """An NI TDMS file replayed as a stream of samples.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.tdms`` file.
    columns : dict, optional
        Role -> ``group/channel`` (or a channel name unique in the file) for ``motor``, ``load``,
        ``torque`` (optional) and ``time`` (optional: default the motor's waveform time).
    units : str, optional
        Overrides the motor and load channels' ``unit_string``.
    motor_cpr, load_cpr : float, optional
        Counts per revolution of channels in encoder counts.
    skip_bad : bool
        Count and skip non-finite or out-of-order samples instead of raising.
    block_rows : int
        Samples read at once (memory stays bounded by it).

    Attributes
    ----------
    counters : StreamCounters
        ``frames`` counts motor samples read; ``frames == samples + corrupt + skipped``.
    nominal_period_s : float or None
        The median time step of the first block, seconds.
    """

    _tdms: Any = None
    _cut = False

    def _open(self) -> tuple[Any, ...]:
        self._tdms, stream, self._cut = _open_tdms(self.path)
        return self._tdms, stream

    def _locate(self, role: str, channels: dict[str, Any]) -> Any:
        name = self.columns[role]
        if name in channels:
            return channels[name]
        by_name = [path for path in channels if path.split("/", 1)[1] == name]
        if len(by_name) == 1:
            return channels[by_name[0]]
        if len(by_name) > 1:
            raise LogFormatError(
                self.path,
                None,
                f"channel {name!r} for {role} is in several groups: {by_name}; name it as GROUP/CHANNEL",
            )
        if role in ("torque", "time") and role not in self.mapped:
            return None
        raise missing_channel(self.path, role, name, channels)

    def _slice(self, role: str, channel: Any, start: int, stop: int) -> np.ndarray:
        try:
            values = channel[start:stop]
        except Exception as exc:  # a damaged segment
            raise LogFormatError(
                self.path, start, f"cannot read {role} channel {self.columns[role]!r} ({type(exc).__name__}: {exc})"
            ) from exc
        if values.dtype.kind not in "biuf":
            raise LogFormatError(
                self.path, start, f"{role} channel {self.columns[role]!r} holds {values.dtype} values, not numbers"
            )
        return values.astype(float, copy=False)

    def _waveform(self, role: str, channel: Any) -> tuple[float, float]:
        """(start, increment) of a channel's waveform time, seconds."""
        props = channel.properties
        if "wf_increment" not in props:
            raise LogFormatError(
                self.path,
                None,
                f"{role} channel {self.columns[role]!r} has no wf_increment property: map a time channel with "
                "columns=/--columns time=GROUP/CHANNEL",
            )
        try:
            increment, start = float(props["wf_increment"]), float(props.get("wf_start_offset", 0.0))
        except (TypeError, ValueError) as exc:
            raise LogFormatError(
                self.path, None, f"{role} channel {self.columns[role]!r}: wf_increment/wf_start_offset are not numbers"
            ) from exc
        if not (np.isfinite(increment) and increment > 0 and np.isfinite(start)):
            raise LogFormatError(
                self.path,
                None,
                f"{role} channel {self.columns[role]!r}: wf_increment {increment!r} is not a positive time step",
            )
        return start, increment

    def _foreign_blocks(self, role: str, channel: Any) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        start, increment = self._waveform(role, channel)
        for first in range(0, len(channel), self.block_rows):
            values = self._slice(role, channel, first, first + self.block_rows)
            yield start + increment * np.arange(first, first + values.size), values

    def _read(self) -> Iterator[SampleChunk]:
        self.counters = StreamCounters()
        try:
            channels = _channels(self._tdms)
        except Exception as exc:
            raise LogFormatError(self.path, None, f"not a readable TDMS file ({type(exc).__name__}: {exc})") from exc
        if self._cut:
            if not self.skip_bad:
                raise LogFormatError(self.path, None, f"{_cut_short(channels)}; --skip-bad-rows reads up to the cut")
            self.counters.frames += 1  # the cut: one corrupt frame, as a CAN log's
            self.counters.corrupt += 1
        read = [r for r in ROLES if r != "torque" or tabular.reads_torque(self.mapped)]
        found: dict[str, Any] = {r: self._locate(r, channels) if r in read else None for r in ROLES}
        used = None if found["torque"] is None else f"{found['torque'].group_name}/{found['torque'].name}"
        self.unused_torque_columns = tabular.torque_like(channels, used)
        present = [r for r in ROLES if found[r] is not None]
        motor = found["motor"]
        n = len(motor)
        aligned = [r for r in present if len(found[r]) == n and found[r].group_name == motor.group_name]
        foreign = {
            r: Resampler(self._foreign_blocks(r, found[r]), self.path, self.columns[r])
            for r in present
            if r not in aligned
        }
        if "time" in foreign:
            raise LogFormatError(
                self.path,
                None,
                f"time channel {self.columns['time']!r} has {len(found['time'])} values, the motor channel {n}",
            )
        units = {r: (found[r].properties.get("unit_string") if r in present else None) for r in ROLES}
        if "time" not in present:
            units["time"] = None
        scales = channel_scales(self.path, self.columns, units, self.units, self.motor_cpr, self.load_cpr)
        wave = None if "time" in present else self._waveform("motor", motor)
        self.time_origin_unix_s = None if wave is None else wf_start_unix_s(motor.properties.get("wf_start_time"))
        self.time_origin_name = "TDMS wf_start_time" if self.time_origin_unix_s is not None else ""
        last_time = -np.inf
        for first in range(0, n, self.block_rows):
            columns = {r: self._slice(r, found[r], first, first + self.block_rows) for r in aligned}
            size = columns["motor"].size
            waveform = None if wave is None else wave[0] + wave[1] * np.arange(first, first + size)
            columns["time"] = columns["time"] * scales[0] if waveform is None else waveform
            chunk, last_time = self._on_motor_time(columns, foreign, first, last_time, scales)
            if len(chunk):
                yield chunk


def wf_start_unix_s(value: Any) -> float | None:
    """A waveform's ``wf_start_time`` (npTDMS gives a UTC ``numpy.datetime64``) in UNIX seconds; None where it
    is missing or not a date after 2001 (LabVIEW writes 1904-01-01 for a waveform without a start time)."""
    if value is None:
        return None
    try:
        if isinstance(value, dt.datetime):  # naive: UTC
            seconds = (value if value.tzinfo is not None else value.replace(tzinfo=dt.timezone.utc)).timestamp()
        else:
            seconds = float(np.datetime64(value, "ns").astype(np.int64)) / 1e9
    except (TypeError, ValueError, OverflowError):
        return None
    return seconds if np.isfinite(seconds) and seconds >= UNIX_TIME_MIN else None


def describe(path: str | os.PathLike[str]) -> tuple[list[ChannelInfo], str | None]:
    """Every ``group/channel`` of a TDMS file with its unit, readable length and waveform rate (``inspect``),
    and why the file is truncated (None when it is whole)."""
    path = os.fspath(path)
    tdms, stream, cut = _open_tdms(path)
    try:
        infos = []
        for name, channel in _channels(tdms).items():
            props = channel.properties
            increment = props.get("wf_increment")
            rate = (
                float(f"{1.0 / float(increment):.6g}")
                if isinstance(increment, (int, float)) and increment > 0
                else None
            )
            dtype = np.dtype(channel.dtype).name if channel.dtype is not None else "none"
            infos.append(ChannelInfo(name, dtype, len(channel), channel.group_name, props.get("unit_string"), rate))
        return infos, _cut_short(_channels(tdms)) if cut else None
    except Exception as exc:
        raise LogFormatError(path, None, f"not a readable TDMS file ({type(exc).__name__}: {exc})") from exc
    finally:
        tdms.close()
        stream.close()


def _describe(path: str, **_: Any) -> FileSummary:
    channels, cut = describe(path)
    return FileSummary(path, "tdms", channels, truncated=cut)


#: NI TDMS files.
TDMS = LogFormat("tdms", (".tdms",), TdmsLog, TABULAR, _describe, title=f"TDMS, {CHANNELS}")
