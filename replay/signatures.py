"""What the files of each binary format start (and end) with, to say in the file's own terms what is
wrong with one its library cannot read: empty, not that format at all, or cut short.

The libraries (npTDMS, asammdf, pyarrow, python-can) fail on such files with their internals
("unpack requires a buffer of 8 bytes"); :func:`check_signature` looks at the file's first and
last bytes before the library opens it, and :func:`library_failure` words a failure after that.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass

from online_backlash.errors import LogFormatError


@dataclass(frozen=True)
class Signature:
    """A format's name as people say it, the bytes its files start with (any of them), and those a whole
    file ends with."""

    kind: str
    starts: tuple[bytes, ...]
    ends: tuple[bytes, ...] = ()

    @property
    def a_file(self) -> str:
        """``a TDMS file``, ``an MDF file``: the article as the name is spoken."""
        return f"{'an' if self.kind[0] in 'AEIMO' else 'a'} {self.kind} file"


def _spelled(marks: tuple[bytes, ...]) -> str:
    return " or ".join(repr(mark.decode("latin-1").strip()) for mark in marks)


#: format name -> signature (TDMS: NI's lead-in tag; MDF: the identification block, "UnFinMF " while a recorder
#: has not finalised it; Parquet: the magic at both ends; Arrow IPC: its magic at both ends; BLF: the file header).
SIGNATURES = {
    "TDMS": Signature("TDMS", (b"TDSm",)),
    "MDF": Signature("MDF", (b"MDF     ", b"UnFinMF ")),
    "Parquet": Signature("Parquet", (b"PAR1",), (b"PAR1",)),
    "Arrow": Signature("Arrow", (b"ARROW1",), (b"ARROW1",)),
    "BLF": Signature("BLF", (b"LOGG",)),
}


def check_signature(path: str | os.PathLike[str], kind: str) -> None:
    """LogFormatError naming ``path`` when it is empty, does not start as a ``kind`` file (a key of :data:`SIGNATURES`)
    does, or misses the end a whole one has (cut short); nothing when it looks whole (or cannot be opened: the
    library's open says why)."""
    sign = SIGNATURES[kind]
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as f:
            head = f.read(max(len(s) for s in sign.starts))
            tail = b""
            if sign.ends:
                f.seek(max(size - max(len(s) for s in sign.ends), 0))
                tail = f.read()
    except OSError:
        return
    if size == 0:
        raise LogFormatError(path, None, f"empty file, not {sign.a_file}")
    if not any(head.startswith(s) for s in sign.starts):
        where = f"where {sign.a_file} starts with {_spelled(sign.starts)}"
        raise LogFormatError(path, None, f"not {sign.a_file}: it starts with {head[:8]!r} {where}")
    if sign.ends and not any(tail.endswith(s) for s in sign.ends):
        ending = f"it does not end with {_spelled(sign.ends)} as a whole one does ({size} bytes)"
        raise LogFormatError(path, None, f"truncated {sign.kind} file: {ending}")


def library_failure(path: str | os.PathLike[str], kind: str, exc: BaseException) -> LogFormatError:
    """The error for a ``kind`` file whose signature is right but that its library cannot read: a read past
    the file's end (struct.error, EOFError) is a file cut short; anything else damage, with the library's words."""
    sign = SIGNATURES[kind]
    if isinstance(exc, (struct.error, EOFError)):
        size = os.path.getsize(path)
        where = f"a block it links to runs past its end ({size} bytes)"
        return LogFormatError(path, None, f"truncated or damaged {sign.kind} file: {where}")
    return LogFormatError(path, None, f"not a readable {sign.kind} file ({type(exc).__name__}: {exc})")
