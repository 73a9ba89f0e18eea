"""HDF5 files (``.h5``, ``.hdf5``: Python, LabVIEW) and MATLAB v7.3 files (``.mat``, HDF5 inside) as a sample source.

Read with h5py. Variables are named ``group/dataset`` in an HDF5 file and ``struct.field`` in a
MATLAB file (:mod:`~online_backlash.replay.variables` says how names, columns, time and units are
found). A MATLAB v7.3 file is HDF5 behind a 512-byte header: MATLAB stores its column-major arrays
transposed (an N x 1 column vector as a 1 x N dataset, an N x k matrix as k x N), marks each
dataset with a ``MATLAB_class`` attribute (``double``, ``char``, ``struct``, ``cell``, a class name
for objects), writes a struct as a group and a char array as UTF-16 code units; the tree is read
in MATLAB's terms (shapes as ``size`` gives them, char arrays as text) and the groups ``#refs#`` and
``#subsystem#`` (cells' and objects' contents) are left out. Units come from a dataset's
``units`` (or ``unit``) attribute. Blocks of ``block_rows`` samples are read as h5py slices, so
memory stays flat however long the file. A file h5py cannot open raises
:class:`~online_backlash.errors.LogFormatError` naming it.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from online_backlash.errors import LogFormatError

from .formats import CHANNELS, TABULAR, LogFormat
from .summary import FileSummary
from .tabular import ChannelInfo
from .variables import Array, Opaque, Struct, Text, VariableLog, VariableTree, describe_tree, sample_index

#: The MATLAB classes of numbers (``MATLAB_class``).
MATLAB_NUMBERS = {
    "double",
    "single",
    "int8",
    "uint8",
    "int16",
    "uint16",
    "int32",
    "uint32",
    "int64",
    "uint64",
    "logical",
}


def _attribute(obj: Any, name: str) -> str | None:
    value = obj.attrs.get(name)
    if value is None:
        return None
    if isinstance(value, np.ndarray):
        value = value.reshape(-1)[0] if value.size else ""
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)


def is_matlab_file(h5: Any) -> bool:
    """True for a MATLAB v7.3 file: its header starts ``MATLAB 7.3 MAT-file``, or its objects carry ``MATLAB_class``."""
    if h5.userblock_size >= 128:
        with open(h5.filename, "rb") as f:
            if f.read(19) == b"MATLAB 7.3 MAT-file":
                return True
    return any("MATLAB_class" in h5[name].attrs for name in list(h5)[:8])


def _tree(h5: Any, path: str) -> VariableTree:
    matlab = is_matlab_file(h5)
    root = Struct("")
    _fill(root, h5, matlab, "." if matlab else "/")
    return VariableTree(path, root, "./" if matlab else "/", "MATLAB" if matlab else "HDF5")


def _fill(struct: Struct, group: Any, matlab: bool, separator: str) -> None:
    import h5py

    for key, obj in group.items():
        if key.startswith("#"):  # MATLAB's storage of cells' and objects' contents
            continue
        name = f"{struct.name}{separator}{key}" if struct.name else key
        kind = _attribute(obj, "MATLAB_class") if matlab else None
        if isinstance(obj, h5py.Group):
            if matlab and kind not in (None, "struct"):
                struct.fields[key] = Opaque(name, f"MATLAB {kind} object")
                continue
            child = Struct(name, parent=struct)
            _fill(child, obj, matlab, separator)
            struct.fields[key] = child
        elif isinstance(obj, h5py.Dataset):
            struct.fields[key] = _leaf(name, obj, kind, matlab)


def _leaf(name: str, dataset: Any, kind: str | None, matlab: bool) -> Array | Text | Opaque:
    shape = tuple(int(n) for n in dataset.shape)
    if matlab:
        shape = shape[::-1]  # MATLAB's column-major array, stored transposed
        if kind == "char":
            return Text(name, "".join(map(chr, np.asarray(dataset[()]).T.reshape(-1))))
        if kind not in MATLAB_NUMBERS or _attribute(dataset, "MATLAB_empty") not in (None, "0"):
            return Opaque(name, f"MATLAB {kind or 'value'}", shape)
    elif dataset.dtype.kind in "SUO":
        value = dataset[()]
        return Text(name, value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value))
    if dataset.dtype.kind not in "biuf":
        return Opaque(name, f"HDF5 {dataset.dtype}", shape)
    unit = _attribute(dataset, "units") or _attribute(dataset, "unit")

    def read(start: int, stop: int, column: int | None) -> np.ndarray:
        index = sample_index(shape, start, stop, column)
        return np.asarray(dataset[index[::-1] if matlab else index])

    return Array(name, shape, dataset.dtype.name, read, unit)


def _open_h5(path: str) -> Any:
    import h5py  # imported on use

    if not os.path.isfile(path):
        raise LogFormatError(path, None, "cannot open: no such file")
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise LogFormatError(path, None, f"not an HDF5 file, or a damaged one ({exc})") from exc


class Hdf5Log(VariableLog):
    """An HDF5 (``.h5``, ``.hdf5``) or MATLAB v7.3 (``.mat``) file replayed as a stream of samples.

    Parameters as :class:`~online_backlash.replay.tabular.MeasurementLog`; ``columns`` maps roles to
    variables (``group/dataset``, ``struct.field``, ``NAME(:,K)``; :mod:`~online_backlash.replay.variables`).
    """

    def _load(self) -> tuple[VariableTree, tuple[Any, ...]]:
        h5 = _open_h5(self.path)
        try:
            return _read_tree(h5, self.path), (h5,)
        except BaseException:
            h5.close()
            raise


def _read_tree(h5: Any, path: str) -> VariableTree:
    """The tree of an open file; a damaged object header raises LogFormatError naming the file."""
    try:
        return _tree(h5, path)
    except LogFormatError:
        raise
    except Exception as exc:
        raise LogFormatError(path, None, f"not a readable HDF5 file ({type(exc).__name__}: {exc})") from exc


def describe(path: str | os.PathLike[str]) -> tuple[str, list[ChannelInfo]]:
    """``("mat-v7.3" or "hdf5", every variable with its shape, type, length, unit)`` (``inspect``)."""
    path = os.fspath(path)
    h5 = _open_h5(path)
    try:
        tree = _read_tree(h5, path)
        return ("mat-v7.3" if tree.kind == "MATLAB" else "hdf5"), describe_tree(tree)
    finally:
        h5.close()


def _describe(path: str, **_: Any) -> FileSummary:
    """An HDF5 file's (or a MATLAB v7.3 file's) variables: ``mat-v7.3`` or ``hdf5``."""
    kind, variables = describe(path)
    return FileSummary(path, kind, variables)


#: HDF5 files.
HDF5 = LogFormat("hdf5", (".h5", ".hdf5"), Hdf5Log, TABULAR, _describe, title=f"HDF5, {CHANNELS}")
