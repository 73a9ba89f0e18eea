"""Parquet and Arrow IPC (Feather v2) tables as a sample source.

Columns are named as in CSV logs (``time``, ``motor``, ``load``, optional ``torque``; ``columns=``
maps other names). A ``timestamp`` or ``duration`` time column is converted to seconds; numeric
columns are read as floats (a null is a non-finite value); the first timestamp of a
``timestamp`` time column (UTC; a timestamp without a zone is read as UTC) is the file's own
clock (:attr:`~online_backlash.stream.SampleSource.time_origin_unix_s`). A column's unit is taken from its
field metadata key ``unit`` where present (else degrees, seconds, N m), and ``units=`` overrides
the angles' units (:func:`~online_backlash.replay.tabular.channel_scales`).

Parquet files stream by batches of ``block_rows`` (``ParquetFile.iter_batches``, a batch's columns
decoded in pyarrow's thread pool; a column's values are handed on without a copy); Arrow IPC
files (``.arrow``, ``.feather``, ``.ipc``) by their record batches, of which only the named columns
are read (and decompressed), in blocks of ``block_rows`` copied out by the checking pass (one record
batch is held at a time: memory is bounded by the file's largest batch). A file pyarrow cannot read raises
:class:`~online_backlash.errors.LogFormatError` naming the file (and the row of the batch that failed).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from online_backlash.errors import LogFormatError
from online_backlash.stream import UNIX_TIME_MIN, SampleChunk, StreamCounters

from .formats import CHANNELS, TABULAR, LogFormat
from .signatures import check_signature, library_failure
from .summary import FileSummary
from .tabular import ROLES, ChannelInfo, MeasurementLog, channel_scales, missing_channel, reads_torque, torque_like

#: Suffixes read as Arrow IPC files rather than Parquet.
ARROW_SUFFIXES = (".arrow", ".feather", ".ipc")


class _Table:
    """One open Parquet or Arrow IPC file: its schema and its batches (pyarrow errors name the file)."""

    def __init__(self, path: str) -> None:
        import pyarrow as pa

        self.path = path
        self.arrow = os.path.splitext(path.lower())[1] in ARROW_SUFFIXES  # an Arrow IPC file, not Parquet
        kind = "Arrow" if self.arrow else "Parquet"
        check_signature(path, kind)
        try:
            if self.arrow:
                # read, not memory-mapped: a map counts every page of the file it touched as resident
                self._source = pa.OSFile(path, "rb")
                self._reader: Any = pa.ipc.open_file(self._source)
            else:
                import pyarrow.parquet as pq  # not for Arrow IPC: it loads pyarrow's file systems (S3, GCS, ...)

                # pyarrow's own file, read without the GIL (a Python file object takes it for every read);
                # buffered column reads, no pre-buffering: memory stays one batch, not one row group
                # (bench/parquet_read.py: whole row groups or pre-buffering cost 50-180 MB more, memory maps
                # count the file's pages as resident, and none of them saves more than a tenth of the CPU)
                self._source = pa.OSFile(path, "rb")
                self._reader = pq.ParquetFile(self._source, pre_buffer=False, buffer_size=1 << 20)
            self.schema = self._reader.schema_arrow if not self.arrow else self._reader.schema
        except OSError as exc:
            if isinstance(exc, FileNotFoundError) or not os.path.isfile(path):
                raise LogFormatError(path, None, f"cannot open: {exc.strerror or exc}") from exc
            self.close()
            raise library_failure(path, kind, exc) from exc
        except Exception as exc:  # pyarrow.ArrowInvalid and friends
            self.close()
            raise library_failure(path, kind, exc) from exc

    @property
    def rows(self) -> int:
        if self.arrow:  # the row count of each batch, reading one column of it
            reader = self._ipc_reader([0] if len(self.schema) else [])
            return sum(reader.get_batch(i).num_rows for i in range(reader.num_record_batches))
        return int(self._reader.metadata.num_rows)

    def _ipc_reader(self, fields: list[int]) -> Any:
        """An Arrow IPC reader of the open file that reads and decompresses only the ``fields`` (indices;
        empty: all), in pyarrow's thread pool."""
        import pyarrow as pa

        return pa.ipc.open_file(self._source, options=pa.ipc.IpcReadOptions(use_threads=True, included_fields=fields))

    def batches(self, names: list[str], block_rows: int) -> Iterator[Any]:
        """Record batches of the named columns, at most ``block_rows`` rows each."""
        row = 0
        try:
            if self.arrow:
                fields = [self.schema.get_field_index(name) for name in names]  # -1: a name held twice
                reader = self._ipc_reader(sorted(set(fields)) if min(fields) >= 0 else [])
                for i in range(reader.num_record_batches):
                    batch = reader.get_batch(i).select(names)
                    for start in range(0, batch.num_rows, block_rows):
                        part = batch.slice(start, block_rows)
                        row += part.num_rows
                        yield part
                    batch = part = None  # released before the next batch is read
            else:
                # the columns of a batch are decoded side by side in pyarrow's thread pool, without the GIL: three
                # quarters of the decode is snappy's decompression, which no option makes cheaper, so the reader's
                # thread hands it to cores the estimator leaves idle instead of doing it all on its own
                for batch in self._reader.iter_batches(batch_size=block_rows, columns=names, use_threads=True):
                    row += batch.num_rows
                    yield batch
        except (OSError, Exception) as exc:  # a damaged page or batch
            if isinstance(exc, LogFormatError):
                raise
            raise LogFormatError(
                self.path, row, f"cannot read the rows after this one ({type(exc).__name__}: {exc})"
            ) from exc

    def close(self) -> None:
        source = getattr(self, "_source", None)
        if source is not None:
            source.close()


def _unit(field: Any) -> str | None:
    meta = field.metadata or {}
    for key in (b"unit", b"units", b"unit_string"):
        if key in meta:
            return meta[key].decode("utf-8", "replace")
    return None


#: Ticks per second of Arrow's time units.
_TICKS_PER_SECOND = {"s": 1, "ms": 1e3, "us": 1e6, "ns": 1e9}


def _as_float(column: Any, role: str, name: str, path: str, row: int, origin: list[int]) -> np.ndarray:
    """A column as float64 (null -> NaN); a timestamp or duration in seconds.

    A timestamp counts from ``origin[0]`` (set to the first one seen: float64 seconds since 1970
    would keep only about 0.2 us), in the column's own integer ticks until then.
    """
    import pyarrow as pa

    kind = column.type
    if pa.types.is_timestamp(kind) or pa.types.is_duration(kind):
        per_second = _TICKS_PER_SECOND[kind.unit]
        ticks = column.cast(pa.int64()).to_numpy(zero_copy_only=False)
        if pa.types.is_timestamp(kind):
            if not origin and len(ticks) and np.isfinite(ticks[0]):
                origin.append(int(ticks[0]))
            ticks = ticks - (origin[0] if origin else 0)
        return ticks.astype(float) / per_second
    if not (pa.types.is_integer(kind) or pa.types.is_floating(kind) or pa.types.is_boolean(kind)):
        raise LogFormatError(path, row, f"{role} column {name!r} holds {kind} values, not numbers")
    if column.null_count:
        column = column.cast(pa.float64()).fill_null(float("nan"))
    if pa.types.is_boolean(kind):  # bit-packed: no buffer to view
        return column.to_numpy(zero_copy_only=False).astype(float, copy=False)
    return _values_of(column).astype(float, copy=False)


def _values_of(column: Any) -> np.ndarray:
    """The values of a primitive numeric Arrow array without nulls, read from its data buffer (no copy).

    ``Array.to_numpy`` gives the same numbers but imports pandas on its first call (pyarrow 26):
    45 MB of resident memory and 0.2 s that a replay of a Parquet file never uses.
    """
    dtype = np.dtype(column.type.to_pandas_dtype())  # a numpy scalar type for a primitive Arrow type
    return np.frombuffer(column.buffers()[1], dtype=dtype, count=len(column), offset=column.offset * dtype.itemsize)


class ParquetLog(MeasurementLog):
    """A Parquet or Arrow IPC table replayed as a stream of samples.

    Parameters
    ----------
    path : str or os.PathLike
        ``.parquet`` (or ``.pq``), ``.arrow``, ``.feather``, ``.ipc``.
    columns : dict, optional
        Role -> column name for ``time``, ``motor``, ``load`` and ``torque`` (optional).
    units : str, optional
        Overrides the motor and load columns' units (default: field metadata ``unit``, else degrees).
    motor_cpr, load_cpr : float, optional
        Counts per revolution of columns in encoder counts.
    skip_bad : bool
        Count and skip rows with non-finite values or a time that goes backwards instead of raising.
    block_rows : int
        Rows read at once (memory stays bounded by it).

    Attributes
    ----------
    counters : StreamCounters
        ``frames`` counts rows read; ``frames == samples + corrupt``.
    nominal_period_s : float or None
        The median time step of the first block, seconds.
    """

    _table: _Table

    def _open(self) -> tuple[Any, ...]:
        self._table = _Table(self.path)
        self.time_origin_unix_s, self.time_origin_name = None, ""
        return (self._table,)

    def _read(self) -> Iterator[SampleChunk]:
        self.counters = StreamCounters()
        table = self._table
        names = table.schema.names
        roles = []
        for role in ROLES:
            if role == "torque" and not reads_torque(self.mapped):
                continue
            if self.columns[role] in names:
                roles.append(role)
            elif role != "torque" or role in self.mapped:
                raise missing_channel(self.path, role, self.columns[role], names, kind="column")
        fields = {r: table.schema.field(self.columns[r]) for r in roles}
        units = {r: _unit(fields[r]) for r in roles}
        scales = channel_scales(self.path, self.columns, units, self.units, self.motor_cpr, self.load_cpr)
        has_torque = "torque" in roles
        self.unused_torque_columns = torque_like(names, self.columns["torque"] if has_torque else None)
        last_time = -np.inf
        for row, arrays in self._arrays(table, roles):
            if scales[0] != 1.0:
                arrays[0] = arrays[0] * scales[0]
            if has_torque and scales[3] != 1.0:
                arrays[3] = arrays[3] * scales[3]
            size = arrays[0].size
            self.counters.frames += size
            # an Arrow IPC record batch is read whole (a million rows of the bench's files, 24 MB) and the block's
            # columns view it: copied out by the checking pass, so that one batch is held at a time, not every
            # batch a block read ahead or waiting for the bookkeeping still views (three: 68 MB)
            chunk, last_time = self._validate_columns(arrays, row, last_time, scales[1:3], copy=table.arrow)
            arrays = []  # the views, released before the next block is read
            if len(chunk):
                yield chunk

    def _arrays(self, table: _Table, roles: list[str]) -> Iterator[tuple[int, list[np.ndarray]]]:
        """(first row, float arrays in ``roles`` order) per batch."""
        import pyarrow as pa

        row = 0
        origin: list[int] = []  # the first timestamp, for a timestamp time column
        time_type = table.schema.field(self.columns["time"]).type
        batches = table.batches([self.columns[r] for r in roles], self.block_rows)
        while (batch := next(batches, None)) is not None:
            arrays = [
                _as_float(batch.column(i), r, self.columns[r], self.path, row, origin) for i, r in enumerate(roles)
            ]
            stamped = origin and pa.types.is_timestamp(time_type)
            start = origin[0] / _TICKS_PER_SECOND[time_type.unit] if stamped else None
            if start is not None and start >= UNIX_TIME_MIN:  # not a device clock counting from 1970
                self.time_origin_unix_s = start
                self.time_origin_name = f"{'Arrow' if self._table.arrow else 'Parquet'} timestamp column"
            rows = batch.num_rows
            batch = None  # neither it nor its columns' views are held while the next batch is read
            yield row, arrays
            arrays = []
            row += rows


def describe(path: str | os.PathLike[str]) -> list[ChannelInfo]:
    """Every column of a Parquet or Arrow file with its type, row count and unit metadata (``inspect``)."""
    table = _Table(os.fspath(path))
    try:
        rows = table.rows
        return [ChannelInfo(field.name, str(field.type), rows, None, _unit(field)) for field in table.schema]
    finally:
        table.close()


def _describer(kind: str) -> Callable[..., FileSummary]:
    def describe_table(path: str, **_: Any) -> FileSummary:
        """The columns of a Parquet or Arrow file."""
        return FileSummary(path, kind, describe(path))

    return describe_table


#: Parquet files, and Arrow IPC files (one reader).
PARQUET = LogFormat(
    "parquet", (".parquet", ".pq"), ParquetLog, TABULAR, _describer("parquet"), title=f"Parquet, {CHANNELS}"
)
ARROW = LogFormat(
    "arrow", (".arrow", ".feather", ".ipc"), ParquetLog, TABULAR, _describer("arrow"), title=f"Arrow IPC, {CHANNELS}"
)
