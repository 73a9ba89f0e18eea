"""Estimators: the paper's batch algorithms and the recursive online estimators."""

from ._base import RecursiveEstimator
from .backlash_rls import BacklashRLS
from .batch import VorosBacklash, VorosCascade
from .cascade_rls import CascadeRLS

__all__ = ["BacklashRLS", "CascadeRLS", "RecursiveEstimator", "VorosBacklash", "VorosCascade"]
