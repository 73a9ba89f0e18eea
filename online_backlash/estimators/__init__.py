"""Estimators: the paper's batch algorithms and the recursive online estimators."""

from .batch import VorosBacklash, VorosCascade

__all__ = ["VorosBacklash", "VorosCascade"]
