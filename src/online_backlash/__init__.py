"""online-backlash: online identification of gearbox backlash from motor and load encoders.

The model is J. Vörös, "Modeling and identification of systems with backlash",
Automatica 46 (2010) 369-374; the recursive form follows J. Vörös, "Recursive identification
of nonlinear cascade systems with time-varying general input backlash", ASME J. Dyn. Sys.
Meas. Control 135(1) 014504 (2013).
"""

from ._version import __version__
from .estimators import BacklashRLS, CascadeRLS, VorosBacklash, VorosCascade
from .stream import Sample

__all__ = ["BacklashRLS", "CascadeRLS", "Sample", "VorosBacklash", "VorosCascade", "__version__"]
