"""Estimators: the paper's batch algorithms and the recursive online estimators on one public base
(:mod:`.base`; a new one is done when :func:`.conformance.check_estimator` passes: ``docs/estimators.md``)."""

from .backlash_rls import BacklashRLS
from .base import EstimateAt, RecursiveEstimator
from .batch import VorosBacklash, VorosCascade
from .cascade_rls import CascadeRLS
from .regressor_rls import RegressorRLS

__all__ = [
    "BacklashRLS",
    "CascadeRLS",
    "EstimateAt",
    "RecursiveEstimator",
    "RegressorRLS",
    "VorosBacklash",
    "VorosCascade",
]
