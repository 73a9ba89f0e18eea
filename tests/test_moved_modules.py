"""The simulators moved into ``online_backlash.simulation`` (issue 29 item 4); their old names still import
them, as the same module objects, and warn the importer that they moved."""

from __future__ import annotations

import subprocess
import sys

import pytest

from online_backlash._moved import MOVED_MODULES as MOVED


def test_the_simulators_old_names_are_kept():
    assert sorted(MOVED) == sorted(
        f"online_backlash.{m}" for m in ("rig", "rig_logs", "two_mass_rig", "wear_logs", "diagnostics.synthetic")
    )


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
