"""A history store filled the way ``track`` fills it, for the tests of the readers of a store (``serve``, ``opcua``,
``check``)."""

from __future__ import annotations

import hashlib

HOUR = 3600.0


def fill_gearbox(
    store, gearbox_id, play_arcmin, end_unix_s, with_parameters, warn=18.0, limit=21.0, std_deg=0.004, **columns
):
    """Hourly estimates of ``play_arcmin`` ending at ``end_unix_s`` in one complete run, each with the standard error
    ``std_deg``; with ``with_parameters`` each also stores eq. (1)'s slopes and dead-band widths (play split evenly);
    ``columns`` are more stored columns of every estimate (``stiffness_nm_per_arcmin=4.25``)."""
    store.set_alarm_levels(gearbox_id, 30.0, warn_arcmin=warn, limit_arcmin=limit)
    gearbox, run = store.begin_run(
        gearbox_id, 30.0, "log.csv", hashlib.sha256(gearbox_id.encode()).hexdigest(), end_unix_s
    )
    n = len(play_arcmin)
    rows = []
    for i, p in enumerate(play_arcmin):
        half = p / 120.0 if with_parameters else None
        slope = 1.0 if with_parameters else None
        rows.append(
            dict(
                sample_index=1000 * (i + 1),
                time_unix_s=end_unix_s - (n - 1 - i) * HOUR,
                backlash_deg=p / 60.0,
                backlash_std_deg=std_deg,
                c_left_deg=half,
                c_right_deg=half,
                m_left=slope,
                m_right=slope,
                residual_rms_deg=None,
                n_samples=1000 * (i + 1),
                operating_hours=float(i + 1),
                load_revolutions=100.0 * (i + 1),
                reversals=50 * (i + 1),
                **columns,
            )
        )
    gearbox, run = store.commit(gearbox, run, 1000 * n, {"format": 1}, rows)
    store.commit(
        gearbox, run, 1000 * n, {"format": 1}, counters=dict(frames=n, samples=n, corrupt=0, skipped=0, gaps=0)
    )
