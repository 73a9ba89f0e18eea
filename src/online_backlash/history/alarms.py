"""Alarm state of a gearbox's play, and its line in the Nagios/Icinga plugin format.

A gearbox has a warning level ``warn_arcmin`` and a limit ``limit_arcmin`` (each optional,
stored with the gearbox by ``track --warn-arcmin/--limit-arcmin``). Its state is read from
its *latest observable estimate*: the latest stored estimate whose play and standard deviation
are both finite (an estimate without a standard deviation was taken while the play was not
observable, e.g. no reversal since the estimator started).

``unknown``
    No limit is known, or there is no observable estimate, or the latest one is older than
    ``max_age_h`` hours of calendar time (default :data:`DEFAULT_MAX_AGE_H`, 7 days: a
    gearbox that ran a log a day and then nothing for a week has no current reading); the
    reason says which (an old estimate is named with its age and date, not as a missing one).
``alarm``
    The play is above the limit (``play > limit``, the plugin convention). The state says
    since when: the time of the first estimate of the trailing run of observable estimates
    all above the limit (``limit_exceeded_since``).
``warning``
    The play is above the warning level (and not above the limit).
``ok``
    Otherwise.

In the plugin format (monitoring-plugins guidelines), ``ok | warning | alarm | unknown`` are
``OK | WARNING | CRITICAL | UNKNOWN`` with exit codes 0/1/2/3, one line of text and the
performance data ``play_arcmin=VALUE;WARN;CRIT`` (``U`` for an unknown value, an empty field
for a level not set)::

    BACKLASH WARNING - GB-7 play 19.2 arcmin, limit 21 in 310 machine hours, around 2026-12-01 | play_arcmin=19.2;18;21

Several gearboxes are summarised by their worst state, in the order ``ok < warning < unknown <
alarm`` (an unknown gearbox may be worn, a gearbox over its limit certainly is).
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidParameterError

#: The states, in order of severity (see :func:`worst_state`).
STATES = ("ok", "warning", "unknown", "alarm")

#: Plugin status word and exit code of each state.
PLUGIN_STATUS = {"ok": ("OK", 0), "warning": ("WARNING", 1), "alarm": ("CRITICAL", 2), "unknown": ("UNKNOWN", 3)}

#: Default age, calendar hours, after which the latest estimate no longer counts as recent.
DEFAULT_MAX_AGE_H = 168.0

ARCMIN_PER_DEG = 60.0


def check_alarm_levels(warn_arcmin: float | None = None, limit_arcmin: float | None = None) -> None:
    """Raise InvalidParameterError unless each given level is finite and positive and ``warn <= limit``.

    Examples
    --------
    >>> check_alarm_levels(18.0, 21.0)
    >>> check_alarm_levels(limit_arcmin=-1.0)
    Traceback (most recent call last):
    ...
    online_backlash.errors.InvalidParameterError: the limit must be a finite positive angle in arcmin, got -1.0
    """
    for name, value in (("warning level", warn_arcmin), ("limit", limit_arcmin)):
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise InvalidParameterError(f"the {name} must be a finite positive angle in arcmin, got {value!r}")
    if warn_arcmin is not None and limit_arcmin is not None and warn_arcmin > limit_arcmin:
        raise InvalidParameterError(
            f"the warning level {warn_arcmin:g} arcmin is above the limit {limit_arcmin:g} arcmin"
        )


@dataclass(frozen=True)
class AlarmStatus:
    """A gearbox's alarm state.

    Attributes
    ----------
    state : str
        ``ok``, ``warning``, ``alarm`` or ``unknown``.
    reason : str
        Why, in a few words (for ``unknown``: what is missing).
    play_arcmin : float or None
        The latest observable estimate of the play, arcmin.
    play_time_unix_s : float or None
        Its calendar time, UNIX seconds.
    warn_arcmin, limit_arcmin : float or None
        The levels it was compared with, arcmin.
    limit_exceeded_since_unix_s : float or None
        In ``alarm``: since when the play is above the limit (see the module docstring).
    """

    state: str
    reason: str
    play_arcmin: float | None
    play_time_unix_s: float | None
    warn_arcmin: float | None
    limit_arcmin: float | None
    limit_exceeded_since_unix_s: float | None = None

    @property
    def plugin_status(self) -> str:
        """``OK``, ``WARNING``, ``CRITICAL`` or ``UNKNOWN``."""
        return PLUGIN_STATUS[self.state][0]

    @property
    def exit_code(self) -> int:
        """0, 1, 2 or 3 (OK, WARNING, CRITICAL, UNKNOWN)."""
        return PLUGIN_STATUS[self.state][1]


def evaluate_alarm(
    time_unix_s: np.ndarray,
    backlash_deg: np.ndarray,
    backlash_std_deg: np.ndarray,
    warn_arcmin: float | None,
    limit_arcmin: float | None,
    now_unix_s: float,
    max_age_h: float = DEFAULT_MAX_AGE_H,
) -> AlarmStatus:
    """The state of a gearbox from its estimates (in order of use; NaN where a value is missing).

    Parameters
    ----------
    time_unix_s, backlash_deg, backlash_std_deg : array
        The stored estimates: calendar time (UNIX seconds), play and its standard deviation (degrees).
    warn_arcmin, limit_arcmin : float or None
        Warning level and limit, arcmin (checked by :func:`check_alarm_levels`).
    now_unix_s : float
        The present, UNIX seconds (wall clock).
    max_age_h : float
        Calendar hours after which the latest observable estimate is too old to count.

    Examples
    --------
    >>> t = np.array([0.0, 3600.0, 7200.0])
    >>> s = evaluate_alarm(t, np.array([0.30, 0.36, 0.37]), np.full(3, 0.001), 18.0, 21.0, now_unix_s=7300.0)
    >>> s.state, s.play_arcmin, s.limit_exceeded_since_unix_s
    ('alarm', 22.2, 3600.0)
    """
    check_alarm_levels(warn_arcmin, limit_arcmin)
    if not (max_age_h > 0):
        raise InvalidParameterError(f"max_age_h must be positive, got {max_age_h!r}")
    t = np.asarray(time_unix_s, dtype=float)
    play = np.asarray(backlash_deg, dtype=float) * ARCMIN_PER_DEG
    observable = np.isfinite(t) & np.isfinite(play) & np.isfinite(np.asarray(backlash_std_deg, dtype=float))
    t, play = t[observable], play[observable]
    levels = {"warn_arcmin": warn_arcmin, "limit_arcmin": limit_arcmin}
    if t.size == 0:
        return AlarmStatus("unknown", "no observable estimate", None, None, **levels)
    last_play, last_time = float(np.round(play[-1], 10)), float(t[-1])
    age_h = (now_unix_s - last_time) / 3600.0
    if age_h > max_age_h:
        when = dt.datetime.fromtimestamp(last_time, dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        old = f"{age_h / 24:.1f} days old ({when})"
        reason = f"the latest observable estimate is {old}, more than the {max_age_h:g} h allowed"
        return AlarmStatus("unknown", reason, last_play, last_time, **levels)
    if limit_arcmin is None:
        return AlarmStatus("unknown", "no limit known", last_play, last_time, **levels)
    if last_play > limit_arcmin:
        below = np.flatnonzero(play <= limit_arcmin)
        first_above = 0 if below.size == 0 else int(below[-1]) + 1
        return AlarmStatus(
            "alarm",
            "play above the limit",
            last_play,
            last_time,
            **levels,
            limit_exceeded_since_unix_s=float(t[first_above]),
        )
    if warn_arcmin is not None and last_play > warn_arcmin:
        return AlarmStatus("warning", "play above the warning level", last_play, last_time, **levels)
    return AlarmStatus(
        "ok",
        "play below the warning level" if warn_arcmin is not None else "play below the limit",
        last_play,
        last_time,
        **levels,
    )


def worst_state(states: list[str]) -> str:
    """The most severe of ``states`` (``ok < warning < unknown < alarm``); ``unknown`` for none."""
    if not states:
        return "unknown"
    return max(states, key=STATES.index)


def _level(value: float | None) -> str:
    return "" if value is None else f"{value:g}"


def plugin_line(gearbox_id: str, status: AlarmStatus, forecast: str) -> str:
    """One line in the Nagios/Icinga plugin format (see the module docstring).

    ``forecast`` is the limit's forecast in a few words, as every reader of the history says it
    (:attr:`~online_backlash.history.text.WearFigures.forecast_short`).

    Examples
    --------
    >>> s = AlarmStatus("warning", "", 19.2, 0.0, 18.0, 21.0)
    >>> plugin_line("GB-7", s, "in 310 machine hours")
    'BACKLASH WARNING - GB-7 play 19.2 arcmin, limit 21 in 310 machine hours | play_arcmin=19.2;18;21'
    """
    text = f"BACKLASH {status.plugin_status} - {gearbox_id}"
    play = status.play_arcmin
    if status.state == "unknown":
        text += f" {status.reason}"
        if play is not None:
            text += f" (last play {play:.1f} arcmin)"
    else:
        text += f" play {play:.1f} arcmin, limit {_level(status.limit_arcmin)} {forecast}"
    value = "U" if play is None else f"{play:.1f}"
    return f"{text} | play_arcmin={value};{_level(status.warn_arcmin)};{_level(status.limit_arcmin)}"
