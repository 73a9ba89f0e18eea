"""The estimate row, declared once: every column of every output that carries an estimate.

An estimate leaves the library in four shapes, and each is a contract (README; tests check
them): the JSON of ``online-backlash estimate --json``, the CSV of ``estimate --trace``, the
``estimates`` table of the wear-history store and the CSV of ``history --csv``. Each column is
declared here once, in :data:`FIELDS` (name, type, unit, meaning); each output is a named
selection of them (:data:`REPORT_KEYS`, :data:`TRACE_COLUMNS`, :data:`STORE_COLUMNS`,
:data:`HISTORY_CSV_COLUMNS`), checked against the table when this module loads. New columns
are added here; names are never changed.

:class:`EstimateRow` is what the pipeline (:mod:`online_backlash.pipeline`) emits every N
seconds of data: the recursive estimator's current estimate, stamped with the time of the
last sample learned. Angles are degrees on the load side, times seconds.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

#: Arc minutes per degree.
ARCMIN_PER_DEG = 60.0


@dataclass(frozen=True)
class RowField:
    """One column of an estimate output.

    Attributes
    ----------
    key : str
        Unique key in :data:`FIELDS`.
    name : str
        The column name or JSON key (two fields may share a name in different outputs:
        ``time`` is seconds in the trace and an ISO 8601 string in ``history --csv``).
    kind : type
        ``float``, ``int`` or ``str``.
    unit : str
        Unit ("" for a pure number).
    doc : str
        Meaning.
    nullable : bool
        May be missing (None / NULL / NaN) in a stored row.
    """

    key: str
    name: str
    kind: type
    unit: str
    doc: str
    nullable: bool = False


def _field(key: str, kind: type, unit: str, doc: str, nullable: bool = False, name: str | None = None) -> RowField:
    return RowField(key, name or key, kind, unit, doc, nullable)


#: Every column, by key.
FIELDS: dict[str, RowField] = {
    f.key: f
    for f in (
        _field("time_s", float, "s", "time of the last sample learned, on the source's clock", name="time"),
        _field("time_iso", str, "", "time_unix_s as ISO 8601 (UTC)", name="time"),
        _field("time_unix_s", float, "s", "calendar time of the last sample learned, UNIX seconds (UTC)"),
        _field(
            "sample_index", int, "", "samples of this run (log or live session) learned when the estimate was taken"
        ),
        _field("run_id", int, "", "the run (one log or live session) the estimate was taken in"),
        _field("samples", int, "", "samples the estimator learned from this log"),
        _field("n_samples", int, "", "samples the estimator learned since the gearbox was new"),
        _field("method", str, "", "'recursive' (BacklashRLS) or 'batch' (VorosBacklash)"),
        _field(
            "backlash_deg",
            float,
            "deg",
            "total play c_left + c_right at the current output level (eq. 1); null where not observable",
            nullable=True,
        ),
        _field("backlash_arcmin", float, "arcmin", "backlash_deg in arc minutes"),
        _field("backlash_std_deg", float, "deg", "standard error of backlash_deg", nullable=True),
        _field("backlash_std_arcmin", float, "arcmin", "backlash_std_deg in arc minutes", nullable=True),
        _field(
            "c_left_deg",
            float,
            "deg",
            "distance from the reference point to the left flank (eq. 1: c_L)",
            nullable=True,
        ),
        _field(
            "c_right_deg",
            float,
            "deg",
            "distance from the reference point to the right flank (eq. 1: c_R)",
            nullable=True,
        ),
        _field("m_left", float, "", "slope of the left flank (eq. 1: m_L)", nullable=True),
        _field("m_right", float, "", "slope of the right flank (eq. 1: m_R)", nullable=True),
        _field("residual_rms_deg", float, "deg", "RMS of the one-step residual (eq. 14)", nullable=True),
        _field("n_reversals", int, "", "reversals of the input the estimator saw", nullable=True),
        _field(
            "play_observable",
            bool,
            "",
            "the data show the play: the torque reversed (with torque), or the load held still while the motor "
            "crossed the gap (without)",
        ),
        _field(
            "torque_reversals",
            int,
            "",
            "changes of the engaged flank (transmitted torque through its dead band); null without torque",
            nullable=True,
        ),
        _field(
            "backlash_lower_bound_deg",
            float,
            "deg",
            "where the play is not resolved: a play it is at least (motor travel with the load still), else null",
            nullable=True,
        ),
        _field(
            "backlash_upper_bound_deg",
            float,
            "deg",
            "where the play is not resolved: a play it is at most (the estimate plus two standard errors), else null",
            nullable=True,
        ),
        _field(
            "reason",
            str,
            "",
            "why backlash_deg is null (not observable, not physical), or that it is a measured zero",
            nullable=True,
        ),
        _field(
            "play_method",
            str,
            "",
            "the play's path: 'torque' (the torque's flank) or 'kinematic' (the motion alone)",
            nullable=True,
        ),
        _field(
            "play_method_reason",
            str,
            "",
            "why that path was taken (the data decide: the torque tested on the dwells)",
            nullable=True,
        ),
        _field(
            "stiffness_nm_per_arcmin",
            float,
            "N m/arcmin",
            "torsional stiffness, mean of both directions (with torque)",
            nullable=True,
        ),
        _field(
            "stiffness_left_nm_per_arcmin",
            float,
            "N m/arcmin",
            "torsional stiffness of the left flank (negative torque)",
            nullable=True,
        ),
        _field(
            "stiffness_right_nm_per_arcmin",
            float,
            "N m/arcmin",
            "torsional stiffness of the right flank (positive torque)",
            nullable=True,
        ),
        _field(
            "lost_motion_arcmin",
            float,
            "arcmin",
            "width of the hysteresis curve at +-3 % of the rated torque (else at the smaller peak torque of the two "
            "directions)",
            nullable=True,
        ),
        _field(
            "hysteresis_loss_arcmin",
            float,
            "arcmin",
            "width of the hysteresis curve at zero torque, torque returned from its peak",
            nullable=True,
        ),
        _field(
            "torque_mean_nm",
            float,
            "N m",
            "mean transmitted torque of the data since the previous estimate; null without torque",
            nullable=True,
        ),
        _field(
            "torque_rms_nm",
            float,
            "N m",
            "RMS transmitted torque of the data since the previous estimate; null without torque",
            nullable=True,
        ),
        _field(
            "operating_hours",
            float,
            "h",
            "operating time since the gearbox was new, counted in the logged samples (UsageCounter)",
        ),
        _field(
            "machine_hours",
            float,
            "h",
            "the machine's hour meter at the estimate (track --operating-hours or --hours-column); null if not given",
            nullable=True,
        ),
        _field("load_revolutions", float, "rev", "load shaft travel since the gearbox was new (UsageCounter)"),
        _field("reversals", int, "", "reversals since the gearbox was new (UsageCounter)"),
        _field("frames", int, "", "raw units the source read: CAN frames, serial frames, data rows of a table"),
        _field(
            "corrupt",
            int,
            "",
            "frames or rows rejected as damaged (bad CRC, unparsable, non-finite; bad rows under --skip-bad-rows)",
        ),
        _field("skipped", int, "", "frames that are not ours (other traffic on a shared bus)"),
        _field(
            "gaps", int, "", "gaps the source reported (counter jumps, steps longer than GAP_PERIODS nominal periods)"
        ),
        _field(
            "unpaired", int, "", "valid frames whose partner (motor or load) never came; 0 for sources of whole samples"
        ),
        _field(
            "gap_longest_s",
            float,
            "s",
            "the longest gap: time step across it, from the sample before to the sample after",
        ),
        _field("gap_total_s", float, "s", "sum of the time steps across every gap"),
        _field(
            "gaps_bridged", int, "", "short gaps the estimator was carried across (state kept; Pipeline's GapPolicy)"
        ),
    )
}


def _view(*keys: str) -> tuple[str, ...]:
    """The column names of an output, from field keys (an unknown key fails at import)."""
    return tuple(FIELDS[k].name for k in keys)


#: Keys of ``estimate --json`` (and ``listen --json``), in this order; more may follow.
REPORT_KEYS = _view(
    "backlash_deg",
    "backlash_arcmin",
    "c_left_deg",
    "c_right_deg",
    "m_left",
    "m_right",
    "samples",
    "residual_rms_deg",
    "method",
    "play_observable",
    "torque_reversals",
    "backlash_lower_bound_deg",
    "stiffness_nm_per_arcmin",
    "stiffness_left_nm_per_arcmin",
    "stiffness_right_nm_per_arcmin",
    "lost_motion_arcmin",
    "hysteresis_loss_arcmin",
    # issue 27: the path of the play and the verdict on it
    "backlash_upper_bound_deg",
    "reason",
    "play_method",
    "play_method_reason",
)
#: Columns of the estimate-over-time trace (``estimate --trace``), in this order.
TRACE_COLUMNS = _view("time_s", "backlash_deg", "backlash_std_deg", "c_left_deg", "c_right_deg", "m_left", "m_right")
#: The fitted lines of eq. (1), their one-step residual and the samples learned: in this order in the store's table
#: and in ``history --csv``.
_FIT_KEYS = ("c_left_deg", "c_right_deg", "m_left", "m_right", "residual_rms_deg", "n_samples")
#: The columns the store gained from schema 3 on, in the order its table and ``history --csv`` both carry them.
_SINCE_SCHEMA_3 = (
    # schema 3: the load condition of each estimate (the wear trend uses only observable ones)
    "play_observable",
    "torque_mean_nm",
    "torque_rms_nm",
    "torque_reversals",
    "stiffness_nm_per_arcmin",
    # schema 4: the machine's hour meter (issue 28)
    "machine_hours",
    # schema 5: the path the play was taken from and why, and what is reported where it is not resolved (issue 27)
    "play_method",
    "play_method_reason",
    "reason",
    "backlash_lower_bound_deg",
    "backlash_upper_bound_deg",
)
#: Columns of the store's ``estimates`` table that a tracker writes (besides ``gearbox_id``, ``run_id``), in table
#: order.
STORE_KEYS = (
    "sample_index",
    "time_unix_s",
    "backlash_deg",
    "backlash_std_deg",
    *_FIT_KEYS,
    "operating_hours",
    "load_revolutions",
    "reversals",
    *_SINCE_SCHEMA_3,
)
STORE_COLUMNS = _view(*STORE_KEYS)
#: Columns of ``history --csv``, in this order.
HISTORY_CSV_COLUMNS = _view(
    "time_iso",
    "time_unix_s",
    "operating_hours",
    "load_revolutions",
    "reversals",
    "backlash_deg",
    "backlash_std_deg",
    "backlash_arcmin",
    "backlash_std_arcmin",
    *_FIT_KEYS,
    "run_id",
    "sample_index",
    *_SINCE_SCHEMA_3,
)

#: The source's counters in every result (``estimate --json``, ``track``, ``diagnose``), in this order.
COUNTER_KEYS = _view("frames", "samples", "corrupt", "skipped", "gaps", "unpaired")
#: The gap figures in every result, in this order (besides the count ``gaps``).
GAP_KEYS = _view("gap_longest_s", "gap_total_s", "gaps_bridged")


def source_counts(counts: Mapping[str, int]) -> dict[str, int]:
    """A source's counters as :data:`COUNTER_KEYS` (a key the source does not count, e.g.
    ``unpaired`` of a CSV log, is 0)."""
    return {name: int(counts.get(name, 0)) for name in COUNTER_KEYS}


def describe_counts(values: Mapping[str, Any]) -> str:
    """The non-zero counters and gap figures of a result as one line (``""`` when all are zero),
    e.g. ``frames 60000, samples 59990, corrupt 10, gaps 2 (longest 0.005 s, total 0.009 s)``."""
    parts = [f"{name} {values[name]}" for name in COUNTER_KEYS if values.get(name)]
    if values.get("gaps"):
        figures = [f"longest {values.get('gap_longest_s', 0.0):.3f} s", f"total {values.get('gap_total_s', 0.0):.3f} s"]
        if values.get("gaps_bridged"):
            figures.append(f"{values['gaps_bridged']} bridged")
        parts = [p + f" ({', '.join(figures)})" if p.startswith("gaps ") else p for p in parts]
    return ", ".join(parts)


def arcmin(value_deg: float | None) -> float | None:
    """Degrees to arc minutes (None stays None)."""
    return None if value_deg is None else value_deg * ARCMIN_PER_DEG


def select(columns: Iterable[str], values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` restricted to ``columns``, in their order (a missing column raises KeyError)."""
    return {name: values[name] for name in columns}


def _torque_values(est: Any) -> dict[str, Any]:
    """The torque-aware figures of a recursive estimator that has them (``takes_torque``), else none."""
    if not getattr(est, "takes_torque", False):
        return {}
    return {
        "torque_reversals": int(est.n_reversals_),
        "stiffness_left_nm_per_arcmin": float(est.stiffness_left_nm_per_arcmin_),
        "stiffness_right_nm_per_arcmin": float(est.stiffness_right_nm_per_arcmin_),
    }


def _mean_or_none(*values: float | None) -> float | None:
    """The mean of the finite values, None if there is none."""
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return sum(finite) / len(finite) if finite else None


@dataclass(frozen=True)
class EstimateRow:
    """The recursive estimator's estimate at one instant (see :data:`FIELDS` for each column).

    ``time_s`` is the time of the last sample learned (the source's clock, seconds); angles in
    degrees on the load side. ``backlash_deg`` is NaN where the play is not reported (``reason``
    says why; :func:`online_backlash.physical.play_verdict`).
    """

    time_s: float
    n_samples: int
    backlash_deg: float
    backlash_std_deg: float
    c_left_deg: float
    c_right_deg: float
    m_left: float
    m_right: float
    residual_rms_deg: float
    n_reversals: int
    torque_reversals: int | None = None
    stiffness_left_nm_per_arcmin: float | None = None
    stiffness_right_nm_per_arcmin: float | None = None
    play_observable: bool = True
    reason: str | None = None
    backlash_lower_bound_deg: float | None = None
    backlash_upper_bound_deg: float | None = None
    play_method: str | None = None
    play_method_reason: str | None = None

    @classmethod
    def from_estimator(cls, est: Any, time_s: float) -> EstimateRow | None:
        """The current estimate of a started recursive estimator, or None while it has none.

        ``est`` has the fitted attributes of :class:`~online_backlash.estimators.BacklashRLS`
        (``started``, ``backlash_``, ``backlash_std_``, ``c_left_``, ``c_right_``, ``m_left_``,
        ``m_right_``, ``residual_rms_``, ``n_samples_seen_``, ``n_reversals_``); an estimator that decides its
        path and verdict itself (:class:`~online_backlash.load_aware.PlayChooser`) gives every column
        (``row_fields()``, None while it has no estimate).
        """
        if not est.started:
            return None
        if hasattr(est, "row_fields"):
            fields = est.row_fields()
            return None if fields is None else cls(time_s=float(time_s), **fields)
        backlash = float(est.backlash_)
        if not math.isfinite(backlash):
            return None
        return cls(
            time_s=float(time_s),
            n_samples=int(est.n_samples_seen_),
            backlash_deg=backlash,
            backlash_std_deg=float(est.backlash_std_),
            c_left_deg=float(est.c_left_),
            c_right_deg=float(est.c_right_),
            m_left=float(est.m_left_),
            m_right=float(est.m_right_),
            residual_rms_deg=float(est.residual_rms_),
            n_reversals=int(est.n_reversals_),
            **_torque_values(est),
        )

    def values(self) -> dict[str, Any]:
        """Every column this row knows, by column name (``time`` is ``time_s``)."""
        return {
            FIELDS["time_s"].name: self.time_s,
            "n_samples": self.n_samples,
            "backlash_deg": self.backlash_deg,
            "backlash_arcmin": self.backlash_deg * ARCMIN_PER_DEG,
            "backlash_std_deg": self.backlash_std_deg,
            "backlash_std_arcmin": self.backlash_std_deg * ARCMIN_PER_DEG,
            "c_left_deg": self.c_left_deg,
            "c_right_deg": self.c_right_deg,
            "m_left": self.m_left,
            "m_right": self.m_right,
            "residual_rms_deg": self.residual_rms_deg,
            "n_reversals": self.n_reversals,
            "play_observable": self.play_observable,
            "torque_reversals": self.torque_reversals,
            "backlash_lower_bound_deg": self.backlash_lower_bound_deg,
            "backlash_upper_bound_deg": self.backlash_upper_bound_deg,
            "reason": self.reason,
            "play_method": self.play_method,
            "play_method_reason": self.play_method_reason,
            "stiffness_nm_per_arcmin": _mean_or_none(
                self.stiffness_left_nm_per_arcmin, self.stiffness_right_nm_per_arcmin
            ),
            "stiffness_left_nm_per_arcmin": self.stiffness_left_nm_per_arcmin,
            "stiffness_right_nm_per_arcmin": self.stiffness_right_nm_per_arcmin,
            "lost_motion_arcmin": None,  # a figure of the whole curve (batch fit), not of a row
            "hysteresis_loss_arcmin": None,
        }

    def trace(self) -> dict[str, float]:
        """The row of ``estimate --trace`` (:data:`TRACE_COLUMNS`)."""
        return select(TRACE_COLUMNS, self.values())
