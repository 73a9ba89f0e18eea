"""What a recorded file holds, for ``online-backlash inspect``: columns, channels or CAN IDs.

:func:`inspect_file` lists a CSV's or Parquet/Arrow table's columns (type, rows), an MDF file's
channels (group, unit, rate, samples), a TDMS file's ``group/channel`` s (unit, length, rate),
a MATLAB or HDF5 file's variables (shape, type, length, unit),
or the CAN IDs seen in a CAN log with their counts, rates and (with a DBC) message names, so a
user with 400 channels finds the two to map with ``--columns``. Nothing is printed here.

Examples
--------
>>> import tempfile, os
>>> folder = tempfile.mkdtemp()
>>> path = os.path.join(folder, "run.csv")
>>> with open(path, "w") as f:
...     _ = f.write("time,motor,load\\n0,0,0\\n0.001,0.1,0\\n")
>>> summary = inspect_file(path)
>>> summary.kind, [(c.name, c.dtype, c.samples) for c in summary.channels]
('csv', [('time', 'float64', 2), ('motor', 'float64', 2), ('load', 'int64', 2)])
"""

from __future__ import annotations

import os

from .errors import LogFormatError
from .replay.paths import file_suffix
from .replay.registry import FORMATS, find_format, suffixes
from .replay.summary import CanIdInfo, ChannelInfo, FileSummary

__all__ = ["CanIdInfo", "ChannelInfo", "FileSummary", "inspect_file"]


def inspect_file(
    path: str | os.PathLike[str], dbc: str | os.PathLike[str] | None = None, **csv_options: str | None
) -> FileSummary:
    """List what the file at ``path`` holds (its format chosen as :func:`~online_backlash.replay.open_log` does).

    ``dbc`` names the CAN IDs of a CAN log; ``csv_options`` (``delimiter``, ``decimal``, ``comment``, ``encoding``)
    override what is sniffed of a CSV (:func:`~online_backlash.replay.csv.sniff_dialect`). Raises LogFormatError for a
    file that cannot be read (a CSV row with another number of fields than its header, named by its line) or a
    format with nothing to list (a raw serial capture).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise LogFormatError(path, None, "no such file" if not os.path.exists(path) else "not a file: inspect one file")
    log_format = find_format(path)
    if log_format is None or log_format.describe is None:
        known = suffixes([f for f in FORMATS if f.describe is not None])
        suffix = file_suffix(path)
        raise LogFormatError(
            path, None, f"inspect reads {', '.join(known)} files, not {suffix or 'files without a suffix'!r}"
        )
    return log_format.describe(path, dbc=dbc, **csv_options)
