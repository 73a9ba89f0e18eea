"""One exception tree and the warnings of online-backlash.

::

    BacklashError
     +-- InvalidParameterError (ValueError, TypeError)  a setting or an argument is out of range
     +-- NotFittedError (ValueError, AttributeError)     a fitted attribute read before fit/learn
     +-- NotExcitedError (ValueError)                    the data cannot identify the model
     +-- SourceError                                     a sample source failed
     |    +-- SourceTimeoutError (TimeoutError)          no data arrived in time
     |    +-- LogFormatError (ValueError)                a log file is malformed (names file and line)
     |    +-- FrameError                                 one frame is corrupt (counted; raised only when strict)
     +-- HistoryError                                    the wear-history store refused an operation

    BacklashWarning (UserWarning)
     +-- ConvergenceWarning                              an iteration stopped at max_iter
     +-- GapWarning                                      a gap in a sample stream

Third-party errors are re-raised ``from`` their cause.
"""

from __future__ import annotations

import os


class BacklashError(Exception):
    """Base class of every error raised on purpose by online-backlash."""


class InvalidParameterError(BacklashError, ValueError, TypeError):
    """A constructor parameter or a function argument is invalid; the message says what was expected."""


class NotFittedError(BacklashError, ValueError, AttributeError):
    """A fitted attribute (name ending in ``_``) was read before ``fit`` or ``learn_one``."""


class NotExcitedError(BacklashError, ValueError):
    """The data do not excite the model, e.g. the input never reverses, so one flank is never seen."""


class SourceError(BacklashError):
    """A sample source (live adapter or log reader) failed."""


class SourceTimeoutError(SourceError, TimeoutError):
    """A live source received nothing within its timeout."""


class LogFormatError(SourceError, ValueError):
    """A recorded log is malformed.

    Parameters
    ----------
    path : str or os.PathLike
        The log file.
    line : int or None
        1-based line number (text logs) or 0-based frame index (binary logs), if known.
    reason : str
        What was wrong, e.g. ``expected 3 columns, got 2``.

    The message reads ``log.csv:1234: expected 3 columns, got 2``.
    """

    def __init__(self, path: str | os.PathLike[str], line: int | None, reason: str) -> None:
        self.path = os.fspath(path)
        self.line = line
        self.reason = reason
        where = self.path if line is None else f"{self.path}:{line}"
        super().__init__(f"{where}: {reason}")


class FrameError(SourceError):
    """A single frame is corrupt (bad checksum, wrong length, non-finite value).

    Sources count such frames in ``counters.corrupt`` and skip them; they raise this
    only when constructed with ``strict=True``.
    """


class HistoryError(BacklashError):
    """The wear-history store refused an operation (not a store, newer schema, unknown gearbox, ...)."""


class BacklashWarning(UserWarning):
    """Base class of the warnings of online-backlash."""


class ConvergenceWarning(BacklashWarning):
    """An iterative fit stopped at ``max_iter`` before meeting its tolerance."""


class GapWarning(BacklashWarning):
    """A sample stream has a gap (missing sequence numbers or a long time step)."""
