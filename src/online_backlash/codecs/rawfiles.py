"""How raw captures are named: written by the live transports, read back by replay.

File names are ``<kind>-<UTC start>-<index>.<suffix>`` (e.g.
``can-20261122T172650_123456Z-0000.blf``), so sorting the names of one directory gives the time
order; the file being written is ``<kind>-<UTC start>-active.<suffix>`` and sorts after the
numbered ones (:mod:`online_backlash.drivers.rawlog` writes them).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

#: suffix of a raw serial capture (bytes as received)
SERIAL_SUFFIX = ".serial"


def raw_log_files(directory: str | os.PathLike[str], suffixes: Iterable[str]) -> list[Path]:
    """The capture files in ``directory`` with one of ``suffixes``, in time (= name) order."""
    wanted = tuple(s.lower() for s in suffixes)
    return sorted(p for p in Path(directory).iterdir() if p.is_file() and p.name.lower().endswith(wanted))
