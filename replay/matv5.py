"""MATLAB files up to v7 (``.mat``: ``save``, Simulink's *To Workspace*, dSPACE exports) as a sample source.

Read with :func:`scipy.io.loadmat`, whole (a v5 file holds each variable as one compressed block,
and MATLAB saves large recordings as v7.3, which streams). Variables are
named ``var`` or ``struct.field`` (``struct/field`` too), a matrix's column ``NAME(:,K)``; how the
time, a signal struct and the units are found: :mod:`~online_backlash.replay.variables`. Shapes are
MATLAB's (a column vector N x 1, a row vector 1 x N: both are read along N). A v7.3 file is HDF5
and is read by :mod:`~online_backlash.replay.hdf5` instead (:func:`is_mat_v73`). A file scipy
cannot read raises :class:`~online_backlash.errors.LogFormatError` naming it.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from online_backlash.errors import LogFormatError
from online_backlash.stream import SampleSource

from .formats import CHANNELS, TABULAR, LogFormat
from .hdf5 import HDF5
from .summary import FileSummary
from .tabular import ChannelInfo
from .variables import Array, Opaque, Struct, Text, VariableLog, VariableTree, describe_tree, sample_index

#: The signature of HDF5 at the end of a MATLAB v7.3 file's 512-byte header.
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def is_mat_v73(path: str | os.PathLike[str]) -> bool:
    """True for a MATLAB v7.3 file (HDF5 after a 512-byte header), False for v4 to v7 (or a file too short to say)."""
    with open(path, "rb") as f:
        f.seek(512)
        return f.read(8) == HDF5_SIGNATURE


def _load_mat(path: str) -> dict[str, Any]:
    from scipy.io import loadmat  # imported on use

    if not os.path.isfile(path):
        raise LogFormatError(path, None, "cannot open: no such file")
    try:
        return loadmat(path, struct_as_record=False, squeeze_me=False)
    except Exception as exc:  # scipy raises ValueError, TypeError, OSError, zlib errors on a damaged file
        raise LogFormatError(path, None, f"not a readable MATLAB file ({type(exc).__name__}: {exc})") from exc


def _tree(path: str, variables: dict[str, Any]) -> VariableTree:
    root = Struct("")
    for key, value in variables.items():
        if not key.startswith("__"):
            root.fields[key] = _node(key, value, root)
    return VariableTree(path, root, "./", "MATLAB")


def _node(name: str, value: Any, parent: Struct) -> Any:
    from scipy.io.matlab import mat_struct

    if (
        isinstance(value, np.ndarray)
        and value.dtype.kind == "O"
        and value.size == 1
        and isinstance(value.flat[0], mat_struct)
    ):
        value = value.flat[0]
    if isinstance(value, mat_struct):
        struct = Struct(name, parent=parent)
        for field in value._fieldnames:
            struct.fields[field] = _node(f"{name}.{field}", getattr(value, field), struct)
        return struct
    array = np.asarray(value)
    if array.dtype.kind == "U":
        return Text(name, "".join(array.reshape(-1)))
    shape = tuple(int(n) for n in array.shape)
    if array.dtype.kind not in "biuf" or array.ndim == 0:
        kind = "cell or struct array" if array.dtype.kind == "O" else f"MATLAB {type(value).__name__}"
        return Opaque(name, kind, shape)

    def read(start: int, stop: int, column: int | None) -> np.ndarray:
        return array[sample_index(shape, start, stop, column)]

    return Array(name, shape, array.dtype.name, read)


class MatV5Log(VariableLog):
    """A MATLAB v4-v7 file replayed as a stream of samples (parameters as :class:`.hdf5.Hdf5Log`)."""

    def _load(self) -> tuple[VariableTree, tuple[Any, ...]]:
        return _tree(self.path, _load_mat(self.path)), ()


def describe(path: str | os.PathLike[str]) -> list[ChannelInfo]:
    """Every variable of a MATLAB v4-v7 file (struct fields too) with its shape, type, length and unit (``inspect``)."""
    path = os.fspath(path)
    return describe_tree(_tree(path, _load_mat(path)))


def _open(path: str | os.PathLike[str], **options: Any) -> SampleSource:
    """A MATLAB file: v7.3 (HDF5 inside) or v4-v7, by its header."""
    if os.path.isfile(path) and is_mat_v73(path):
        return HDF5.open(path, **options)
    return MatV5Log(path, **options)


def _describe(path: str, **_: Any) -> FileSummary:
    assert HDF5.describe is not None
    return HDF5.describe(path) if is_mat_v73(path) else FileSummary(path, "mat", describe(path))


#: MATLAB files, v4-v7 (scipy) and v7.3 (HDF5 inside).
MAT = LogFormat("mat", (".mat",), _open, TABULAR, _describe, title=f"MATLAB v4-v7.3, {CHANNELS}")
