"""Load-aware play: the transmitted torque says which flank carries the load (issue 12).

With a torque column the engaged flank is *measured* (:mod:`.engagement`) instead of inferred
from the motion, so the flank offsets and the torsional compliance of each direction are
estimated by linear least squares (:mod:`.flank_fit`, batch) or one RLS per flank
(:mod:`.torque_rls`, recursive); the play is observable only where the torque reverses
(:mod:`.observability`); :mod:`.datasheet` gives the data-sheet figures (stiffness, lost motion,
hysteresis loss) of the torsion-angle/torque curve. The data decide whether the torque path holds
(issue 27): :mod:`.choice` tests it against the dwells of the motion, :class:`PlayChooser` carries
that choice through a stream.
"""

from .chooser import PlayChooser
from .datasheet import DatasheetFigures, datasheet_figures, torsion_curve
from .engagement import count_torque_reversals, engaged_flank, torque_deadband, torque_noise_std
from .flank_fit import TorqueBacklash
from .observability import DwellTracker
from .torque_rls import TorqueBacklashRLS

__all__ = [
    "DatasheetFigures",
    "DwellTracker",
    "PlayChooser",
    "TorqueBacklash",
    "TorqueBacklashRLS",
    "count_torque_reversals",
    "datasheet_figures",
    "engaged_flank",
    "torque_deadband",
    "torque_noise_std",
    "torsion_curve",
]
