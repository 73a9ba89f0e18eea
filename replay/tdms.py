"""NI TDMS files (LabVIEW rigs) as a sample source.

Channels are named ``group/channel`` (``columns={"motor": "Encoders/Motor", "load":
"Encoders/Load"}``); a bare channel name is accepted when one group holds it. Time comes from the
motor channel's waveform properties (``wf_start_offset + i * wf_increment``, seconds) or from
a channel mapped to ``time``. A channel of another length or rate is interpolated linearly onto
the motor's time base from its own waveform time (motor samples outside its span are counted in
``counters.skipped``). The ``unit_string`` property decides each channel's unit as in
:func:`~online_backlash.replay.tabular.channel_scales` (no property: degrees, seconds, N m);
``units=`` overrides the angles' units.

The file is opened with ``TdmsFile.open`` (streaming) and read in slices of ``block_rows``, so
memory stays flat. A file npTDMS cannot read raises :class:`~online_backlash.errors.LogFormatError`
naming the file and the channel.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import IO, Any

import numpy as np

from online_backlash.errors import LogFormatError
from online_backlash.stream import SampleChunk, StreamCounters

from . import tabular
from .tabular import ROLES, ChannelInfo, MeasurementLog, Resampler, channel_scales, missing_channel, open_with


def _open_tdms(path: str) -> tuple[Any, IO[bytes]]:
    """npTDMS's streaming reader over a file object this module closes (npTDMS leaves it open when it fails)."""
    from nptdms import TdmsFile  # imported on use

    return open_with(path, "TDMS", TdmsFile.open)


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

    def _open(self) -> tuple[Any, ...]:
        self._tdms, stream = _open_tdms(self.path)
        return self._tdms, stream

    def _locate(self, role: str, channels: dict[str, Any]) -> Any:
        name = self.columns[role]
        if name in channels:
            return channels[name]
        by_name = [path for path in channels if path.split("/", 1)[1] == name]
        if len(by_name) == 1:
            return channels[by_name[0]]
        if len(by_name) > 1:
            raise LogFormatError(self.path, None, f"channel {name!r} for {role} is in several groups: {by_name}; name it as GROUP/CHANNEL")
        if role in ("torque", "time") and role not in self.mapped:
            return None
        raise missing_channel(self.path, role, name, channels)

    def _slice(self, role: str, channel: Any, start: int, stop: int) -> np.ndarray:
        try:
            values = channel[start:stop]
        except Exception as exc:  # a damaged segment
            raise LogFormatError(self.path, start, f"cannot read {role} channel {self.columns[role]!r} ({type(exc).__name__}: {exc})") from exc
        if values.dtype.kind not in "biuf":
            raise LogFormatError(self.path, start, f"{role} channel {self.columns[role]!r} holds {values.dtype} values, not numbers")
        return values.astype(float, copy=False)

    def _waveform(self, role: str, channel: Any) -> tuple[float, float]:
        """(start, increment) of a channel's waveform time, seconds."""
        props = channel.properties
        if "wf_increment" not in props:
            raise LogFormatError(
                self.path,
                None,
                f"{role} channel {self.columns[role]!r} has no wf_increment property: map a time channel with columns=/--columns time=GROUP/CHANNEL",
            )
        try:
            increment, start = float(props["wf_increment"]), float(props.get("wf_start_offset", 0.0))
        except (TypeError, ValueError) as exc:
            raise LogFormatError(self.path, None, f"{role} channel {self.columns[role]!r}: wf_increment/wf_start_offset are not numbers") from exc
        if not (np.isfinite(increment) and increment > 0 and np.isfinite(start)):
            raise LogFormatError(self.path, None, f"{role} channel {self.columns[role]!r}: wf_increment {increment!r} is not a positive time step")
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
        read = [r for r in ROLES if r != "torque" or tabular.reads_torque(self.mapped)]
        found: dict[str, Any] = {r: self._locate(r, channels) if r in read else None for r in ROLES}
        used = None if found["torque"] is None else f"{found['torque'].group_name}/{found['torque'].name}"
        self.unused_torque_columns = tabular.torque_like(channels, used)
        present = [r for r in ROLES if found[r] is not None]
        motor = found["motor"]
        n = len(motor)
        aligned = [r for r in present if len(found[r]) == n and found[r].group_name == motor.group_name]
        foreign = {r: Resampler(self._foreign_blocks(r, found[r]), self.path, self.columns[r]) for r in present if r not in aligned}
        if "time" in foreign:
            raise LogFormatError(self.path, None, f"time channel {self.columns['time']!r} has {len(found['time'])} values, the motor channel {n}")
        units = {r: (found[r].properties.get("unit_string") if r in present else None) for r in ROLES}
        if "time" not in present:
            units["time"] = None
        scales = channel_scales(self.path, self.columns, units, self.units, self.motor_cpr, self.load_cpr)
        wave = None if "time" in present else self._waveform("motor", motor)
        has_torque = "torque" in present
        last_time = -np.inf
        for first in range(0, n, self.block_rows):
            columns = {r: self._slice(r, found[r], first, first + self.block_rows) for r in aligned}
            size = columns["motor"].size
            time = columns["time"] * scales[0] if wave is None else wave[0] + wave[1] * np.arange(first, first + size)
            inside = np.ones(size, bool)
            for r, resampler in foreign.items():
                columns[r], ok = resampler.at(time)
                inside &= ok
            self.counters.frames += size
            self.counters.skipped += int(np.count_nonzero(~inside))
            arrays = [time, columns["motor"], columns["load"]] + ([columns["torque"] * scales[3]] if has_torque else [])
            numbers: np.ndarray | int = first
            if not inside.all():
                arrays, numbers = [a[inside] for a in arrays], np.flatnonzero(inside) + first
            chunk, last_time = self._validate_columns(arrays, numbers, last_time, scales[1:3])
            if len(chunk):
                yield chunk


def describe(path: str | os.PathLike[str]) -> list[ChannelInfo]:
    """Every ``group/channel`` of a TDMS file with its unit, length and waveform rate (``inspect``)."""
    path = os.fspath(path)
    tdms, stream = _open_tdms(path)
    try:
        infos = []
        for name, channel in _channels(tdms).items():
            props = channel.properties
            increment = props.get("wf_increment")
            rate = float(f"{1.0 / float(increment):.6g}") if isinstance(increment, (int, float)) and increment > 0 else None
            dtype = np.dtype(channel.dtype).name if channel.dtype is not None else "none"
            infos.append(ChannelInfo(name, dtype, len(channel), channel.group_name, props.get("unit_string"), rate))
        return infos
    except Exception as exc:
        raise LogFormatError(path, None, f"not a readable TDMS file ({type(exc).__name__}: {exc})") from exc
    finally:
        tdms.close()
        stream.close()
