"""The simulators moved into ``online_backlash.simulation`` (issue 29 item 4); their old names still import
them, as the same module objects, and warn the importer that they moved."""

from __future__ import annotations

import subprocess
import sys

import pytest

MOVED = {
    "online_backlash.rig": "online_backlash.simulation.rig",
    "online_backlash.rig_logs": "online_backlash.simulation.rig_logs",
    "online_backlash.two_mass_rig": "online_backlash.simulation.two_mass_rig",
    "online_backlash.wear_logs": "online_backlash.simulation.wear_logs",
    "online_backlash.diagnostics.synthetic": "online_backlash.simulation.synthetic",
}


@pytest.mark.parametrize("old", sorted(MOVED))
def test_an_old_name_is_the_new_module_and_warns(old):
    # a fresh interpreter: an old name warns once, where it is first imported
    code = (
        "import importlib, sys, warnings\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        f"    old = importlib.import_module({old!r})\n"
        f"assert old is importlib.import_module({MOVED[old]!r})\n"
        "assert [w.category for w in caught] == [DeprecationWarning], caught\n"
        f"assert {MOVED[old]!r} in str(caught[0].message)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
