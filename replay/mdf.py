"""ASAM MDF measurement files (``.mf4``, ``.mdf``; CANape, INCA, dSPACE recorders) as a sample source.

Channels are found by name (``columns={"motor": "EncMotor", "load": "EncLoad"}``; ``NAME@GROUP``
picks one of several channels of one name). The motor channel's group sets the time base: its
master channel (or the channel mapped to ``time``). Channels of other groups, recorded at other
rates, are interpolated linearly onto it; motor samples outside their recorded span are counted
in ``counters.skipped``, as are records in which the motor, load, torque or time channel is marked
invalid (MDF4 invalidation bits). asammdf applies each channel's conversion; the channel's unit decides
its scale (:func:`~online_backlash.replay.tabular.channel_scales`: angle units to degrees, counts
with ``motor_cpr``/``load_cpr``), unless ``units=`` overrides it.

The file is read through a plain file object (no memory map) in fragments of about
``fragment_bytes``, so memory stays flat whatever the file's length. Each fragment of the motor's
channel group is read once for all its channels (master time included); a plain channel (byte
aligned, little endian, no conversion) is viewed where it lies in the records and copied out by
the block checks' one compiled pass, the others are converted by asammdf. A file asammdf cannot read
raises :class:`~online_backlash.errors.LogFormatError` naming the file (and the channel). The
header's start time, which the master times count from, is the file's own clock
(:attr:`~online_backlash.stream.SampleSource.time_origin_unix_s`, :func:`header_start_unix_s`).

An MDF file that holds CAN bus logging (``CAN_DataFrame`` channels, as python-can and bus
loggers write) is a CAN log: :func:`is_bus_logging` tells them apart.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import io
import math
import os
from collections.abc import Iterator
from typing import IO, Any

import numpy as np

from online_backlash.errors import LogFormatError
from online_backlash.stream import UNIX_TIME_MIN, SampleChunk, StreamCounters

from . import tabular
from .formats import CHANNELS, MF4, TABULAR, LogFormat
from .paths import file_suffix
from .summary import FileSummary
from .tabular import ChannelInfo, MeasurementLog, Resampler, channel_scales, missing_channel, open_with

#: One fragment of a channel: time (s), values, unit string.
_Fragment = tuple[np.ndarray, np.ndarray, str]
#: Channel names of ASAM MDF bus logging (CAN frames recorded as such).
BUS_LOGGING_CHANNELS = ("CAN_DataFrame", "CANFD_DataFrame")


def _open_mdf(path: str) -> tuple[Any, IO[bytes]]:
    """asammdf's MDF over a plain file object (flat memory: no memory map); errors name the file."""
    # python-can before asammdf: asammdf imports python-can, whose MF4 support imports asammdf back, and begun
    # from asammdf that circle leaves python-can's MF4 reader disabled for the process (a bus-logging .mf4)
    import can  # noqa: F401
    from asammdf import MDF  # imported on use: asammdf is heavy

    return open_with(path, "MDF", MDF, _release_half_built)


def _release_half_built(exc: BaseException) -> None:
    """Close what asammdf (8.x) leaves open when opening a damaged file fails.

    Its reader object is then half built: its ``__del__`` raises on missing attributes and its
    temporary file stays open (a ResourceWarning). Found in the failing frames, the object gets
    its temporary file closed and is marked closed, so that its ``__del__`` does nothing.
    """
    tb = exc.__traceback__
    while tb is not None:
        obj = tb.tb_frame.f_locals.get("self")
        if obj is not None and hasattr(obj, "_tempfile") and callable(getattr(obj, "close", None)):
            temporary = getattr(obj, "_tempfile", None)
            if temporary is not None:
                temporary.close()
            obj._closed = True
        tb = tb.tb_next


def _quiet_stdout() -> contextlib.AbstractContextManager[Any]:
    """Silence what asammdf prints on stdout while it reads (8.x prints a ``MB/s`` line whenever
    reading a channel group takes over 10 s, e.g. a long file, which would corrupt ``--json``).
    The reader thread's few calls are the only prints in that window: the CLI prints after reading."""
    return contextlib.redirect_stdout(io.StringIO())


def is_bus_logging(path: str | os.PathLike[str]) -> bool:
    """True when the MDF file records CAN frames (bus logging), not measured signals."""
    mdf, stream = _open_mdf(os.fspath(path))
    try:
        return any(name.split(".")[0] in BUS_LOGGING_CHANNELS for name in mdf.channels_db)
    finally:
        mdf.close()
        stream.close()


class MdfLog(MeasurementLog):
    """An ASAM MDF (3 or 4) measurement file replayed as a stream of samples.

    Parameters
    ----------
    path : str or os.PathLike
        The file (``.mf4``, ``.mdf``).
    *args, **kwargs
        Those of :class:`~online_backlash.replay.tabular.TabularSource`: ``columns`` (role -> channel name for
        ``motor``, ``load``, ``torque`` (optional) and ``time`` (optional: default the motor group's master
        channel)), ``units`` (overrides the channels' units), ``motor_cpr``, ``load_cpr``, ``skip_bad``.
    fragment_bytes : int
        Size hint of the blocks read from the file (memory stays bounded by it). 512 KiB (21,845
        samples of motor, load and time in 24-byte records): about six blocks are in flight at once
        (read ahead, learned, waiting for the bookkeeping), and the MDF reader's imports (asammdf with
        pandas, pyarrow and python-can: 90 MB) leave little room, so 2 MiB took the peak RSS of
        ``estimate`` on 10 M samples to 310 MB and 1 MiB to 300 (issue 31's bound), 512 KiB to 295, for no
        CPU measurably lost (``bench/end_to_end.py``, ``docs/benchmarks.md``).

    Attributes
    ----------
    counters : StreamCounters
        ``frames`` counts records of the motor's group read; ``frames == samples + corrupt + skipped``.
    nominal_period_s : float or None
        The median time step of the first block, seconds.
    """

    def __init__(self, path: str | os.PathLike[str], *args: Any, fragment_bytes: int = 1 << 19, **kwargs: Any) -> None:
        super().__init__(path, *args, **kwargs)
        self.fragment_bytes = int(fragment_bytes)
        self._mdf: Any = None

    def _open(self) -> tuple[Any, ...]:
        self._mdf, stream = _open_mdf(self.path)
        self._mdf.configure(read_fragment_size=self.fragment_bytes)
        self.time_origin_unix_s = header_start_unix_s(self._mdf)
        self.time_origin_name = "MDF header start time" if self.time_origin_unix_s is not None else ""
        return self._mdf, stream

    # -- channels --------------------------------------------------------------------------
    def _locate(self, role: str) -> tuple[int, int] | None:
        """(group, index) of the channel mapped to ``role``; None for an absent optional torque."""
        name = self.columns[role]
        base, at, group = name.rpartition("@")
        if at and group.isdigit():
            name = base
        found = self._mdf.channels_db.get(name, ())
        if at and group.isdigit():
            found = tuple(entry for entry in found if entry[0] == int(group))
        if not found:
            if role == "torque" and "torque" not in self.mapped:
                return None
            raise missing_channel(self.path, role, self.columns[role], self._mdf.channels_db)
        if len(found) > 1:
            groups = sorted(g for g, _ in found)
            raise LogFormatError(
                self.path, None, f"channel {name!r} for {role} is in several groups {groups}; name one as {name}@GROUP"
            )
        return found[0]

    def _fragments(self, role: str, where: tuple[int, int]) -> Iterator[_Fragment]:
        """(time_s, values, unit) per file fragment of a channel of another group than the motor's;
        asammdf's errors name the file and channel."""
        signals = self._mdf.iter_get(group=where[0], index=where[1])
        while True:
            try:
                with _quiet_stdout():
                    signal = next(signals)
            except StopIteration:
                return
            except Exception as exc:  # a damaged data block
                raise LogFormatError(
                    self.path, None, f"cannot read {role} channel {self.columns[role]!r} ({type(exc).__name__}: {exc})"
                ) from exc
            values = signal.samples
            if values.dtype.kind not in "biuf":
                raise LogFormatError(
                    self.path, None, f"{role} channel {self.columns[role]!r} holds {values.dtype} values, not numbers"
                )
            yield np.asarray(signal.timestamps, dtype=float), values.astype(float, copy=False), signal.unit

    def _read(self) -> Iterator[SampleChunk]:
        self.counters = StreamCounters()
        where = {r: self._locate(r) for r in ("motor", "load")}
        where["torque"] = self._locate("torque") if tabular.reads_torque(self.mapped) else None
        used = self.columns["torque"] if where["torque"] is not None else None
        self.unused_torque_columns = tabular.torque_like(self._mdf.channels_db, used)
        if "time" in self.mapped:
            where["time"] = self._locate("time")
        present = [r for r in ("time", "motor", "load", "torque") if where.get(r) is not None]
        motor_group = where["motor"][0]  # type: ignore[index]
        aligned = {r: where[r][1] for r in present if where[r][0] == motor_group}  # type: ignore[index]
        foreign = {
            r: Resampler(((t, v) for t, v, _ in self._fragments(r, where[r])), self.path, self.columns[r])  # type: ignore[arg-type]
            for r in present
            if r not in aligned
        }
        units: dict[str, str | None] = {r: self._unit_of((motor_group, i)) or "" for r, i in aligned.items()}
        units.update({r: self._unit_of(where[r]) for r in foreign})  # type: ignore[arg-type]
        if "time" not in self.mapped:
            units["time"] = None
        scales: tuple[float, float, float, float] | None = None
        has_torque = "torque" in present
        row = 0
        last_time = -np.inf
        for master, columns, valid in self._group_records(motor_group, aligned):
            time = columns.pop("time", master)
            inside = np.ones(time.size, bool) if valid is None else valid
            for r, resampler in foreign.items():
                columns[r], ok = resampler.at(time)
                inside &= ok
            if scales is None:
                scales = channel_scales(self.path, self.columns, units, self.units, self.motor_cpr, self.load_cpr)
            self.counters.frames += time.size
            self.counters.skipped += int(np.count_nonzero(~inside))
            arrays = [time if scales[0] == 1.0 else time * scales[0], columns["motor"], columns["load"]]
            if has_torque:
                arrays.append(columns["torque"] * scales[3])
            numbers: np.ndarray | int = row
            if not inside.all():
                arrays, numbers = [a[inside] for a in arrays], np.flatnonzero(inside) + row
            row += time.size
            # the record views share asammdf's read buffer, which the next fragment overwrites: copied here
            chunk, last_time = self._validate_columns(arrays, numbers, last_time, scales[1:3], copy=True)
            if len(chunk):
                yield chunk

    def _group_records(
        self, group: int, channels: dict[str, int]
    ) -> Iterator[tuple[np.ndarray, dict[str, np.ndarray], np.ndarray | None]]:
        """(master time, role -> values, valid) per fragment of one channel group, its records read once for all its
        channels.

        ``valid`` is False for the records in which one of the channels is marked invalid (MDF4
        invalidation bits; None when none of them has any).

        A byte-aligned little-endian number without a conversion is viewed in the records as it
        lies (:func:`_record_field`); other channels, and the master, are taken from the same
        fragment by asammdf (conversions applied). asammdf's errors name the file and the channels.
        """
        from asammdf.blocks.v4_constants import FLAG_CG_REMOTE_MASTER

        mdf = self._mdf
        fields = {r: _record_field(mdf, group, i) for r, i in channels.items()}
        master_index = mdf.masters_db.get(group)
        remote = mdf.groups[group].channel_group.flags & FLAG_CG_REMOTE_MASTER  # the master lies in another group
        master_field = _record_field(mdf, group, master_index) if master_index is not None and not remote else None
        fragments = mdf._mdf._load_data(
            mdf.groups[group]
        )  # the group's records in fragments, as asammdf's own iter_get reads them
        names = ", ".join(f"{r} {self.columns[r]!r}" for r in channels)
        while True:
            try:
                with _quiet_stdout():
                    fragment = next(fragments, None)
                    if fragment is None:
                        return
                    master = (
                        mdf.get_master(group, data=fragment)
                        if master_field is None
                        else _values(fragment, master_field)
                    )
                    columns = {r: _in_records(fragment, fields[r], mdf, group, i) for r, i in channels.items()}
                    valid = _valid(fragment, mdf, group, list(channels.values()), len(master))
            except Exception as exc:  # a damaged data block
                raise LogFormatError(
                    self.path, None, f"cannot read channel group {group} ({names}) ({type(exc).__name__}: {exc})"
                ) from exc
            for r, values in columns.items():
                if values.dtype.kind not in "biuf":
                    raise LogFormatError(
                        self.path, None, f"{r} channel {self.columns[r]!r} holds {values.dtype} values, not numbers"
                    )
            yield np.asarray(master, dtype=float), {r: v.astype(float, copy=False) for r, v in columns.items()}, valid

    def _unit_of(self, where: tuple[int, int]) -> str | None:
        """A channel's unit as asammdf gives it with the samples: its conversion's unit, else its own."""
        channel = self._mdf.groups[where[0]].channels[where[1]]
        conversion = getattr(channel, "conversion", None)
        return (conversion is not None and getattr(conversion, "unit", None)) or getattr(channel, "unit", None)


def header_start_unix_s(mdf: Any) -> float | None:
    """The measurement's start (the header's start time, which the master channels' times count from), UNIX seconds.

    An MDF4 header holds it in UTC with the recorder's zone offset, or as local time with no zone
    (then read as UTC); MDF3 as a date and time. None where it is not a date after 2001 (a
    recorder that left it 0 or never set its clock).
    """
    try:
        start = mdf.header.start_time
    except (AttributeError, ValueError, OverflowError, OSError):
        return None
    if start.tzinfo is None:  # local time of an unknown zone: taken as UTC
        start = start.replace(tzinfo=dt.timezone.utc)
    value = start.timestamp()
    return value if math.isfinite(value) and value >= UNIX_TIME_MIN else None


def describe(path: str | os.PathLike[str]) -> list[ChannelInfo]:
    """Every channel of an MDF file with its group, unit, sample count and rate (``inspect``)."""
    path = os.fspath(path)
    mdf, stream = _open_mdf(path)
    try:
        infos = []
        for g, group in enumerate(mdf.groups):
            records = int(group.channel_group.cycles_nr)
            rate = _group_rate(mdf, g, records)
            for channel in group.channels:
                dtype = f"{_DATA_TYPES.get(channel.data_type, 'bytes')}{channel.bit_count}"
                infos.append(ChannelInfo(channel.name, dtype, records, g, channel.unit or "", rate))
        return infos
    except LogFormatError:
        raise
    except Exception as exc:
        raise LogFormatError(path, None, f"not a readable MDF file ({type(exc).__name__}: {exc})") from exc
    finally:
        mdf.close()
        stream.close()


#: A channel's record field: byte offset in the record, numpy type, record size (bytes).
_Field = tuple[int, np.dtype, int]
#: MDF4 little-endian data types that lie in a record as numpy reads them: unsigned, signed, IEEE float.
_PLAIN_KINDS = {0: "u", 2: "i", 4: "f"}


def _record_field(mdf: Any, group: int, index: int) -> _Field | None:
    """Where a channel lies in its group's records, if numpy can view it there as it is (else None).

    That is an MDF4 channel with a fixed-length value (or master), little endian, byte aligned,
    of a whole numpy size, without conversion, in a group of sorted records without record IDs.
    """
    if not str(mdf.version).startswith("4"):
        return None
    grp = mdf.groups[group]
    channel = grp.channels[index]
    kind = _PLAIN_KINDS.get(channel.data_type)
    size, rest = divmod(channel.bit_count, 8)
    record = grp.channel_group.samples_byte_nr + grp.channel_group.invalidation_bytes_nr
    if (
        kind is None
        or rest
        or size not in ((4, 8) if kind == "f" else (1, 2, 4, 8))
        or channel.bit_offset
        or channel.channel_type not in (0, 2)  # fixed-length value, master
        or channel.conversion is not None
        or grp.data_group.record_id_len
        or grp.uses_ld
        or grp.channel_dependencies[index]
        or channel.byte_offset + size > grp.channel_group.samples_byte_nr
    ):
        return None
    return channel.byte_offset, np.dtype(f"<{kind}{size}"), record


def _valid(fragment: Any, mdf: Any, group: int, channels: list[int], records: int) -> np.ndarray | None:
    """False for the records of a fragment in which one of ``channels`` is marked invalid (MDF4 invalidation
    bits, in each record after its samples or, for column storage, in the fragment's invalidation data);
    None when none of them carries invalidation bits."""
    from asammdf.blocks.v4_constants import FLAG_CN_ALL_INVALID, FLAG_CN_INVALIDATION_PRESENT

    if not str(mdf.version).startswith("4"):
        return None
    grp = mdf.groups[group]
    sizes = grp.channel_group
    valid = None
    for index in channels:
        channel = grp.channels[index]
        if channel.flags & FLAG_CN_ALL_INVALID:
            return np.zeros(records, bool)
        if not channel.flags & FLAG_CN_INVALIDATION_PRESENT:
            continue
        if grp.uses_ld:
            data, offset, stride = fragment.invalidation_data, 0, sizes.invalidation_bytes_nr
        else:
            data, offset, stride = (
                fragment.data,
                sizes.samples_byte_nr,
                sizes.samples_byte_nr + sizes.invalidation_bytes_nr,
            )
        bits = np.ndarray(
            (records,), np.uint8, buffer=data, offset=offset + channel.pos_invalidation_bit // 8, strides=(stride,)
        )
        ok = (bits >> (channel.pos_invalidation_bit % 8)) & 1 == 0
        valid = ok if valid is None else valid & ok
    return valid


def _in_records(fragment: Any, field: _Field | None, mdf: Any, group: int, index: int) -> np.ndarray:
    """A channel's values in a fragment of records: viewed where it lies (``field``), else as asammdf gives them
    (its conversion applied)."""
    if field is not None:
        return _values(fragment, field)
    return mdf.get(group=group, index=index, data=fragment, samples_only=True, ignore_invalidation_bits=True)[0]


def _values(fragment: Any, field: _Field) -> np.ndarray:
    """A channel's values in a fragment of records (a strided view of asammdf's buffer, not a copy)."""
    offset, dtype, record = field
    count = len(fragment.data) // record
    return (
        np.ndarray((count,), dtype, buffer=fragment.data, offset=offset, strides=(record,))
        if count
        else np.empty(0, dtype)
    )


#: MDF4 channel data types (little/big endian) -> numpy-like kind names, for ``inspect``.
_DATA_TYPES = {0: "uint", 1: "uint", 2: "int", 3: "int", 4: "float", 5: "float"}


def _group_rate(mdf: Any, group: int, records: int) -> float | None:
    """Sampling rate of a channel group from its master channel's first two samples, Hz."""
    if records < 2:
        return None
    master = mdf.get_master(group, record_offset=0, record_count=min(records, 1000))
    steps = np.diff(np.asarray(master, dtype=float))
    steps = steps[steps > 0]
    return float(f"{1.0 / np.median(steps):.6g}") if steps.size else None


def _describe(path: str, **_: Any) -> FileSummary:
    return FileSummary(path, "mdf", describe(path))


def _holds_signals(path: str | os.PathLike[str]) -> bool:
    """An ``.mdf`` is always measured signals; an ``.mf4`` only when it is a file not of CAN bus logging."""
    return file_suffix(path) != MF4 or (os.path.isfile(path) and not is_bus_logging(path))


#: MDF measured signals (an ``.mf4`` of CAN bus logging is :data:`~online_backlash.replay.formats.CAN`'s).
MDF = LogFormat("mdf", (MF4, ".mdf"), MdfLog, TABULAR, _describe, recognises=_holds_signals, title=f"MDF, {CHANNELS}")
