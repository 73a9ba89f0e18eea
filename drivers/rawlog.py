"""Raw captures written before anything is parsed, named so that sorting gives time order.

CAN frames go through python-can's own writers, rotated by :class:`can.SizedRotatingLogger`;
serial bytes are appended verbatim. File names are ``<kind>-<UTC start>-<index>.<suffix>``
(e.g. ``can-20261122T172650_123456Z-0000.blf``), so sorting the names of one directory gives
the time order (:mod:`online_backlash.codecs.rawfiles` states the naming, which replay reads
too), and concatenating the files gives exactly the frames (CAN) or bytes (serial)
received. The file being written is ``<kind>-<UTC start>-active.<suffix>`` (it sorts after the
numbered ones) and takes its number when rotated or closed. Nothing else is written there.
"""

from __future__ import annotations

import os
from datetime import datetime, timezone
from pathlib import Path
from typing import BinaryIO

import can

from online_backlash.codecs.rawfiles import SERIAL_SUFFIX, raw_log_files
from online_backlash.errors import InvalidParameterError, SourceError

from .live import CAN_RAW_FORMATS


def _start_stamp() -> str:
    return datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S_%fZ")


class RawCanLog(can.Listener):
    """A Listener that writes every frame to ``directory`` with python-can's writers.

    Parameters
    ----------
    directory : path
        Created if missing.
    fmt : {"blf", "asc", "log"}
        BLF (binary, compact), ASC (Vector text) or candump ``.log``.
    max_bytes : int
        Start a new file when the current one reaches this size.
    container_bytes : int
        BLF only: frames buffered in memory before they are compressed and written (python-can's
        ``max_container_size``); a crash loses at most this much.

    Attributes
    ----------
    frames : int
        Frames written.
    """

    def __init__(
        self,
        directory: str | os.PathLike[str],
        fmt: str = "blf",
        max_bytes: int = 64 * 2**20,
        container_bytes: int = 16 * 2**10,
    ) -> None:
        if fmt not in CAN_RAW_FORMATS:
            raise InvalidParameterError(f"raw CAN log format must be one of {CAN_RAW_FORMATS}, got {fmt!r}")
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self._prefix = f"can-{_start_stamp()}"
        self._suffix = f".{fmt}"
        self._active = self.directory / f"{self._prefix}-active{self._suffix}"
        kwargs = {"max_container_size": container_bytes} if fmt == "blf" else {}
        self._logger = can.SizedRotatingLogger(self._active, max_bytes=max_bytes, **kwargs)
        self._logger.namer = lambda _default: self._numbered(self._logger.rollover_count)
        self.frames = 0
        self._stopped = False

    def _numbered(self, index: int) -> str:
        return str(self.directory / f"{self._prefix}-{index:04d}{self._suffix}")

    def on_message_received(self, msg: can.Message) -> None:
        self._logger.on_message_received(msg)
        self.frames += 1

    def stop(self) -> None:
        """Flush and close the current file and give it its number."""
        if self._stopped:
            return
        self._stopped = True
        self._logger.stop()
        if self._active.exists():
            os.rename(self._active, self._numbered(self._logger.rollover_count))

    @property
    def files(self) -> list[Path]:
        """The files of this capture, in time order."""
        return [p for p in raw_log_files(self.directory, [self._suffix]) if p.name.startswith(self._prefix)]


class RawByteLog:
    """Append bytes verbatim to ``serial-<UTC start>-<index>.serial`` files in ``directory``.

    Each :meth:`write` is flushed to the operating system before it returns, so the bytes are on
    disk (in the OS cache) before the caller parses them.
    """

    def __init__(self, directory: str | os.PathLike[str], max_bytes: int = 64 * 2**20, kind: str = "serial") -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.max_bytes = int(max_bytes)
        self._prefix = f"{kind}-{_start_stamp()}"
        self._index = 0
        self._file: BinaryIO | None = None
        self.bytes_written = 0
        self._open()

    def _open(self) -> None:
        self._file = open(self.directory / f"{self._prefix}-{self._index:04d}{SERIAL_SUFFIX}", "ab")

    def write(self, data: bytes) -> None:
        """Append ``data`` and flush; rotate when the file reaches ``max_bytes``."""
        if self._file is None:
            raise SourceError(f"capture {self._prefix} is closed")
        self._file.write(data)
        self._file.flush()
        self.bytes_written += len(data)
        if self.max_bytes > 0 and self._file.tell() >= self.max_bytes:
            self._file.close()
            self._index += 1
            self._open()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    @property
    def files(self) -> list[Path]:
        """The files of this capture, in time order."""
        return [p for p in raw_log_files(self.directory, [SERIAL_SUFFIX]) if p.name.startswith(self._prefix)]
