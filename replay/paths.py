"""What a log file's name says about its format."""

from __future__ import annotations

import os


def file_suffix(path: str | os.PathLike[str]) -> str:
    """The suffix that selects a file's reader, lower case, a ``.gz`` looked through: ``.csv`` for ``Run.CSV.gz``.

    Examples
    --------
    >>> file_suffix("logs/Run.CSV.gz"), file_suffix("rig.blf"), file_suffix("notes")
    ('.csv', '.blf', '')
    """
    name = os.fspath(path).lower()
    if name.endswith(".gz"):
        name = name[:-3]
    return os.path.splitext(name)[1]
