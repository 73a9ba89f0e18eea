"""Renamed to :mod:`online_backlash.gap_policy` (issue 29).

This old name still imports it, with a DeprecationWarning.
"""

from ._moved import alias_moved_module

alias_moved_module(__name__)
