"""What MATLAB and HDF5 files share: a tree of named arrays, names resolved to roles, blocks read along samples.

A MATLAB file (:mod:`~online_backlash.replay.matv5`, :mod:`~online_backlash.replay.hdf5` for v7.3) or
an HDF5 file is read as a tree: :class:`Struct` nodes (MATLAB structs, HDF5 groups) holding
:class:`Array` leaves (numeric arrays), :class:`Text` leaves (char arrays, strings) and
:class:`Opaque` leaves (cells, objects: listed, never read). A role is mapped to a name:

* ``meas.EncMotor_deg`` (a struct's field; ``/`` works too) or ``group/dataset`` in HDF5;
* ``NAME(:,K)``: column K (1-based, as MATLAB writes it) of a matrix whose rows are samples;
* a struct standing for a signal: a Simulink ``timeseries`` saved as a struct (``Time``, ``Data``)
  or a *Structure With Time* export (``time``, ``signals.values``): the name of the struct reads its
  ``Data``/``data``/``values``/``Values`` (or ``signals.values``).

Samples run along a vector's length, or down a matrix's rows (MATLAB's N x k of k signals; an
HDF5 dataset's first axis). The time base is the variable mapped to ``time``, else the time vector
beside the motor's data: the nearest ``time``, ``Time`` or ``t`` in the struct holding it or in a
struct above. Another role with a time vector of its own (another struct, another rate) is
interpolated onto the motor's time base (:class:`~online_backlash.replay.tabular.Resampler`);
without one it must have the motor's length. Units: a ``units``/``unit`` attribute (HDF5), else a
``units``/``Units``/``unit`` text field of the signal struct, else degrees (seconds, N m), unless
``units=`` overrides them (:func:`~online_backlash.replay.tabular.channel_scales`). Memory stays
within a few blocks of ``block_rows`` samples wherever the format reads slices (HDF5, MATLAB v7.3).
"""

from __future__ import annotations

import re
from abc import abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from online_backlash.errors import LogFormatError
from online_backlash.stream import SampleChunk, StreamCounters

from .tabular import ROLES, TIME_UNITS, ChannelInfo, MeasurementLog, Resampler, channel_scales, missing_channel

#: A struct's fields that hold a signal's values (a timeseries saved as a struct, a Simulink export).
DATA_FIELDS = ("Data", "data", "values", "Values", "signals")
#: Names of the time vector beside a signal, nearest first.
TIME_FIELDS = ("time", "Time", "t")
#: A signal struct's text fields that name its unit.
UNIT_FIELDS = ("units", "Units", "unit", "Unit")

#: ``NAME(:,K)``: column K of a matrix.
_COLUMN = re.compile(r"^(?P<name>.+?)\s*\(\s*:\s*,\s*(?P<column>\d+)\s*\)$")

#: Reads ``values[start:stop]`` along the sample axis of one column (None: a vector) as floats.
Reader = Callable[[int, int, "int | None"], np.ndarray]


@dataclass
class Array:
    """A numeric array: ``shape`` as its author sees it (MATLAB's rows x columns; numpy's for HDF5)."""

    name: str
    shape: tuple[int, ...]
    dtype: str
    read: Reader
    unit: str | None = None

    @property
    def samples(self) -> int:
        """The length along the sample axis: a vector's length, a matrix's rows."""
        if len([n for n in self.shape if n != 1]) <= 1:
            return int(max(self.shape, default=0)) if all(self.shape) else 0
        return int(self.shape[0])

    @property
    def columns(self) -> int:
        """Signals side by side: 1 for a vector, a matrix's columns."""
        return 1 if len([n for n in self.shape if n != 1]) <= 1 else int(np.prod(self.shape[1:]))


@dataclass
class Text:
    """A char array or string (a unit's name)."""

    name: str
    value: str


@dataclass
class Opaque:
    """What holds no numbers to read: a cell array, a MATLAB object (``kind`` names it)."""

    name: str
    kind: str
    shape: tuple[int, ...] = ()


@dataclass
class Struct:
    """A MATLAB struct or an HDF5 group: fields by name, in file order."""

    name: str
    fields: dict[str, Any] = field(default_factory=dict)
    parent: Struct | None = None

    def arrays(self) -> Iterator[Array]:
        """Every numeric array in the tree below, depth first."""
        for node in self.fields.values():
            if isinstance(node, Array):
                yield node
            elif isinstance(node, Struct):
                yield from node.arrays()

    def leaves(self) -> Iterator[tuple[Array | Opaque, Struct]]:
        """Every array and opaque value below with the struct holding it, depth first (what ``inspect`` lists)."""
        for node in self.fields.values():
            if isinstance(node, (Array, Opaque)):
                yield node, self
            elif isinstance(node, Struct):
                yield from node.leaves()


@dataclass(frozen=True)
class Signal:
    """A role's variable: the array, its column (None: a vector), its unit, and the struct it was found in."""

    array: Array
    column: int | None
    unit: str | None
    home: Struct

    def read(self, start: int, stop: int) -> np.ndarray:
        return self.array.read(start, stop, self.column)


def sample_index(shape: tuple[int, ...], start: int, stop: int, column: int | None) -> tuple[Any, ...]:
    """The numpy index of ``[start:stop]`` along the sample axis of an array of ``shape`` (author's order)."""
    along = slice(start, stop)
    if len([n for n in shape if n != 1]) <= 1:  # a vector, however it is laid out
        axis = int(np.argmax(shape)) if shape else 0
        return tuple(along if i == axis else 0 for i in range(len(shape)))
    return (along, 0 if column is None else column) + (0,) * (len(shape) - 2)


class VariableTree:
    """Names of a file's tree resolved to signals (see the module docstring); ``separators`` split a name."""

    def __init__(self, path: str, root: Struct, separators: str, kind: str) -> None:
        self.path = path
        self.root = root
        self.separators = separators
        self.kind = kind

    def names(self) -> list[str]:
        return [a.name for a in self.root.arrays()]

    def find(self, role: str, name: str) -> Signal | None:
        """The signal named ``name`` (None if there is no such name); errors name the role."""
        found = _COLUMN.match(name)
        column = int(found["column"]) - 1 if found else None
        parts = [p for p in re.split(f"[{re.escape(self.separators)}]", found["name"] if found else name) if p]
        node: Any = self.root
        holder = self.root  # the struct the name ends in: where a time vector beside it is looked for
        for part in parts:
            if not isinstance(node, Struct) or part not in node.fields:
                return None
            holder, node = node, node.fields[part]
        unit = None
        while isinstance(node, Struct):  # a struct standing for a signal: its data field
            data = next((node.fields[f] for f in DATA_FIELDS if f in node.fields), None)
            if data is None:
                raise LogFormatError(
                    self.path, None, f"{role} {name!r} is a struct without {'/'.join(DATA_FIELDS[:3])}: name a field"
                )
            unit = unit or _unit_field(node)
            holder, node = node, data
        if isinstance(node, Opaque):
            raise LogFormatError(self.path, None, f"{role} {name!r} is a {node.kind}, not numbers; {_OPAQUE_HINT}")
        if isinstance(node, Text):
            raise LogFormatError(self.path, None, f"{role} {name!r} is text ({node.value[:20]!r}), not numbers")
        self._check_column(role, name, node, column)
        return Signal(node, column, node.unit or unit, holder)

    def _check_column(self, role: str, name: str, array: Array, column: int | None) -> None:
        if array.samples == 0:
            raise LogFormatError(self.path, None, f"{role} {name!r} is empty ({_shape(array.shape)})")
        if array.columns > 1 and len(array.shape) > 2:
            raise LogFormatError(
                self.path, None, f"{role} {name!r} is a {_shape(array.shape)} array: name a vector or a matrix's column"
            )
        if column is None and array.columns > 1:
            raise LogFormatError(
                self.path,
                None,
                f"{role} {name!r} is a {_shape(array.shape)} matrix: name one column, "
                f"e.g. {name}(:,1)..{name}(:,{array.columns})",
            )
        if column is not None and not 0 <= column < array.columns:
            raise LogFormatError(
                self.path, None, f"{role} {name!r} has {array.columns} columns ({_shape(array.shape)})"
            )

    def signal(self, role: str, name: str) -> Signal:
        """The signal named ``name``; a missing name raises the error listing the closest names."""
        found = self.find(role, name)
        if found is None:
            raise missing_channel(self.path, role, name, self.names(), kind="variable")
        return found

    def time_beside(self, signal: Signal) -> Signal | None:
        """The nearest ``time``/``Time``/``t`` vector in the struct of ``signal`` or a struct above it."""
        home: Struct | None = signal.home
        while home is not None:
            for name in TIME_FIELDS:
                node = home.fields.get(name)
                if isinstance(node, Array) and node is not signal.array and node.columns == 1:
                    return Signal(node, None, node.unit, home)
            home = home.parent
        return None


_OPAQUE_HINT = "save it as a struct (Time and Data fields) or as plain arrays: only MATLAB can decode its objects"


def _unit_field(struct: Struct) -> str | None:
    for name in UNIT_FIELDS:
        node = struct.fields.get(name)
        if isinstance(node, Text):
            return node.value
    return None


def _shape(shape: tuple[int, ...]) -> str:
    return "x".join(str(n) for n in shape) or "scalar"


def describe_tree(tree: VariableTree) -> list[ChannelInfo]:
    """Every array (and opaque value) of a tree with its shape, type, length, unit and, where a time vector lies
    beside it, its sampling rate (``inspect``)."""
    infos = []
    for leaf, home in tree.root.leaves():
        if isinstance(leaf, Array):
            rate = _rate(tree.time_beside(Signal(leaf, None, leaf.unit, home)))
            infos.append(ChannelInfo(leaf.name, leaf.dtype, leaf.samples, None, leaf.unit, rate, _shape(leaf.shape)))
        else:
            infos.append(ChannelInfo(leaf.name, leaf.kind, None, None, None, shape=_shape(leaf.shape)))
    return infos


def _rate(time: Signal | None, head: int = 1000) -> float | None:
    """The sampling rate, Hz, of a time vector (its first ``head`` steps' median; None: none, or in unknown units)."""
    scale = TIME_UNITS.get((time.unit or "s").strip().lower()) if time is not None else None
    if time is None or scale is None or time.array.samples < 2:
        return None
    steps = np.diff(np.asarray(time.read(0, min(time.array.samples, head + 1)), dtype=float) * scale)
    steps = steps[np.isfinite(steps) & (steps > 0)]
    return float(f"{1.0 / np.median(steps):.6g}") if steps.size else None


class VariableLog(MeasurementLog):
    """Base of the MATLAB and HDF5 readers: roles resolved in the file's tree, blocks read along the samples.

    A subclass writes :meth:`_load` (open the file; its tree and what :meth:`close` must close).
    Parameters as :class:`~online_backlash.replay.tabular.MeasurementLog`; ``columns`` maps roles to
    variable names (see the module docstring).

    Attributes
    ----------
    counters : StreamCounters
        ``frames`` counts the motor's samples read; ``frames == samples + corrupt + skipped``
        (``skipped``: motor samples outside another role's recorded span).
    """

    _tree: VariableTree

    @abstractmethod
    def _load(self) -> tuple[VariableTree, tuple[Any, ...]]:
        """Open the file: its tree, and the objects to close."""

    def _open(self) -> tuple[Any, ...]:
        self._tree, handles = self._load()
        return handles

    def _signals(self) -> dict[str, Signal]:
        tree = self._tree
        signals = {r: tree.signal(r, self.columns[r]) for r in ("motor", "load")}
        torque = tree.find("torque", self.columns["torque"])
        if torque is not None:
            signals["torque"] = torque
        elif "torque" in self.mapped:
            tree.signal("torque", self.columns["torque"])  # raises, listing the closest names
        if "time" in self.mapped:
            signals["time"] = tree.signal("time", self.columns["time"])
        else:
            beside = tree.time_beside(signals["motor"])
            if beside is None:
                raise LogFormatError(
                    self.path,
                    None,
                    f"no time vector for motor {self.columns['motor']!r}: "
                    f"none named {', '.join(TIME_FIELDS)} beside it; "
                    "map one with columns=/--columns time=NAME",
                )
            signals["time"] = beside
            self.columns = {**self.columns, "time": beside.array.name}
        return signals

    def _read(self) -> Iterator[SampleChunk]:
        self.counters = StreamCounters()
        signals = self._signals()
        motor, time = signals["motor"], signals["time"]
        n = motor.array.samples
        if time.array.samples != n:
            raise LogFormatError(
                self.path,
                None,
                f"time {time.array.name!r} has {time.array.samples} values, motor {motor.array.name!r} {n}",
            )
        aligned = ["time", "motor"]
        foreign: dict[str, Resampler] = {}
        for role in ("load", "torque"):
            if role not in signals:
                continue
            own = self._tree.time_beside(signals[role])
            if own is None or own.array is time.array:
                if signals[role].array.samples != n:
                    raise LogFormatError(
                        self.path,
                        None,
                        f"{role} {signals[role].array.name!r} has {signals[role].array.samples} values, motor {n}, "
                        "and no time vector of its own",
                    )
                aligned.append(role)
            else:
                foreign[role] = Resampler(self._blocks(own, signals[role]), self.path, self.columns[role])
        units = {r: (signals[r].unit if r in signals else None) for r in ROLES}
        scales = channel_scales(self.path, self.columns, units, self.units, self.motor_cpr, self.load_cpr)
        last_time = -np.inf
        for first in range(0, n, self.block_rows):
            stop = min(first + self.block_rows, n)
            columns = {r: self._values(signals[r], r, first, stop) for r in aligned}
            columns["time"] = columns["time"] * scales[0]
            chunk, last_time = self._on_motor_time(columns, foreign, first, last_time, scales)
            if len(chunk):
                yield chunk

    def _blocks(self, time: Signal, values: Signal) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """(time, values) of a role on its own time base, in blocks (for the resampler)."""
        scale = channel_scales(
            self.path, {**self.columns, "time": time.array.name}, {"time": time.unit}, None, None, None
        )[0]
        for first in range(0, values.array.samples, self.block_rows):
            stop = min(first + self.block_rows, values.array.samples)
            yield self._values(time, "time", first, stop) * scale, self._values(values, "values", first, stop)

    def _values(self, signal: Signal, role: str, start: int, stop: int) -> np.ndarray:
        try:
            return np.asarray(signal.read(start, stop), dtype=float).reshape(-1)
        except Exception as exc:  # a damaged chunk of the file
            raise LogFormatError(
                self.path, start, f"cannot read {role} {signal.array.name!r} ({type(exc).__name__}: {exc})"
            ) from exc
