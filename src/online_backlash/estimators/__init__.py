"""Estimators: the paper's batch algorithms and the recursive online estimators."""

from .batch import VorosBacklash, VorosCascade
from .recursive import BacklashRLS, CascadeRLS

__all__ = ["BacklashRLS", "CascadeRLS", "VorosBacklash", "VorosCascade"]
