"""Old module names kept importable after a move: the old name is the new module, with a DeprecationWarning."""

from __future__ import annotations

import importlib
import sys
import warnings
from types import ModuleType

#: old name -> new name of every module moved or renamed (issue 29: the simulators into ``simulation/``, and
#: three top-level modules to names that say what they hold); each old name's file calls :func:`alias_moved_module`
MOVED_MODULES = {
    "online_backlash.rig": "online_backlash.simulation.rig",
    "online_backlash.rig_logs": "online_backlash.simulation.rig_logs",
    "online_backlash.two_mass_rig": "online_backlash.simulation.two_mass_rig",
    "online_backlash.wear_logs": "online_backlash.simulation.wear_logs",
    "online_backlash.diagnostics.synthetic": "online_backlash.simulation.synthetic",
    "online_backlash.rows": "online_backlash.output_columns",
    "online_backlash.fitting": "online_backlash.log_fit",
    "online_backlash.bridging": "online_backlash.gap_policy",
}


def alias_moved_module(old: str) -> ModuleType:
    """Make the module ``old`` (being imported) the module it moved to, and warn the importer that it moved.

    Called from the body of the old module's file: ``sys.modules[old]`` becomes the new module, so
    ``import old`` and ``from old import name`` give the new module's objects themselves (the same
    classes, one numba cache), private names included.
    """
    new = MOVED_MODULES[old]
    warnings.warn(
        f"{old} has moved to {new}: import it from there ({old} will be removed in a later release)",
        DeprecationWarning,
        stacklevel=3,  # the import statement that named the old module (the import machinery is skipped)
    )
    module = importlib.import_module(new)
    sys.modules[old] = module
    return module
