"""The simulators moved into ``online_backlash.simulation`` (issue 29 item 4) and three top-level modules were
renamed (item 6: ``rows``, ``fitting``, ``bridging``); their old names still import them, as the same module
objects, and warn the importer that they moved."""

from __future__ import annotations

import subprocess
import sys

import pytest

from online_backlash._moved import MOVED_MODULES as MOVED


def test_the_old_names_are_kept():
    simulators = ("rig", "rig_logs", "two_mass_rig", "wear_logs", "diagnostics.synthetic")
    renamed = ("rows", "fitting", "bridging")
    assert sorted(MOVED) == sorted(f"online_backlash.{m}" for m in simulators + renamed)
    assert [MOVED[f"online_backlash.{m}"] for m in renamed] == [
        "online_backlash.output_columns",
        "online_backlash.log_fit",
        "online_backlash.gap_policy",
    ]


@pytest.mark.parametrize("old", sorted(MOVED))
def test_an_old_name_is_the_new_module_and_warns(old):
    # a fresh interpreter: an old name warns once, where it is first imported
    code = (
        "import importlib, sys, warnings\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        f"    import {old} as old\n"
        f"assert old is importlib.import_module({MOVED[old]!r})\n"
        "assert [w.category for w in caught] == [DeprecationWarning], caught\n"
        f"assert {MOVED[old]!r} in str(caught[0].message)\n"
        "assert caught[0].filename == '<string>', caught[0].filename  # the importer's line, not ours\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_an_old_name_gives_the_same_classes():
    # what a user's code imported by the old names is the new modules' objects themselves
    with pytest.warns(DeprecationWarning, match="online_backlash.output_columns"):
        from online_backlash.rows import FIELDS, EstimateRow
    from online_backlash import gap_policy, log_fit, output_columns

    assert (EstimateRow, FIELDS) == (output_columns.EstimateRow, output_columns.FIELDS)
    with pytest.warns(DeprecationWarning, match="online_backlash.gap_policy"):
        from online_backlash.bridging import GapPolicy, GapTally
    assert (GapPolicy, GapTally) == (gap_policy.GapPolicy, gap_policy.GapTally)
    with pytest.warns(DeprecationWarning, match="online_backlash.log_fit"):
        from online_backlash.fitting import fit_batch
    assert fit_batch is log_fit.fit_batch


def test_describe_is_report_text_and_warns():
    from online_backlash.log_fit import BacklashReport, describe, report_text

    report = BacklashReport("batch", 10, 0.5, 0.25, -0.25, 1.0, 1.0, 0.01)
    with pytest.warns(DeprecationWarning, match="report_text"):
        text = describe(report, "run.csv")
    assert text == report_text(report, "run.csv") and text.startswith("log:            run.csv")
