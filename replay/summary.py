"""What a recorded file holds, as ``inspect`` lists it: :class:`FileSummary` (channels or CAN IDs), :class:`CanIdInfo`.

Each format's ``describe`` (:class:`~online_backlash.replay.formats.LogFormat`) returns a :class:`FileSummary`.
"""

from __future__ import annotations

import fnmatch
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from .tabular import ChannelInfo

__all__ = ["CanIdInfo", "ChannelInfo", "FileSummary"]


@dataclass(frozen=True)
class CanIdInfo:
    """One CAN ID seen in a log: ``frames`` frames at ``rate_hz`` (None for a single frame), DBC ``message`` name if
    known."""

    can_id: int
    extended: bool
    frames: int
    rate_hz: float | None = None
    message: str | None = None

    @property
    def label(self) -> str:
        """The ID as written in DBCs and candump: ``0x123`` or ``0x18FF0001x`` (extended)."""
        return f"0x{self.can_id:08X}x" if self.extended else f"0x{self.can_id:03X}"


@dataclass
class FileSummary:
    """What :func:`inspect_file` found in ``path`` (a file of format ``kind``); ``truncated`` says why a file is
    cut short (None when whole): the counts are then what is readable up to the cut."""

    path: str
    kind: str
    channels: list[ChannelInfo] = field(default_factory=list)
    can_ids: list[CanIdInfo] = field(default_factory=list)
    frames: int | None = None
    truncated: str | None = None

    def matching(self, pattern: str | None) -> FileSummary:
        """The summary restricted to names matching a shell pattern (``*enc*``), case-insensitive; a plain word matches
        as a substring."""
        if not pattern:
            return self
        glob = pattern.lower() if any(ch in pattern for ch in "*?[") else f"*{pattern.lower()}*"
        return replace(
            self,
            channels=[c for c in self.channels if fnmatch.fnmatchcase(c.name.lower(), glob)],
            can_ids=[i for i in self.can_ids if fnmatch.fnmatchcase(f"{i.label} {i.message or ''}".lower(), glob)],
        )

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict: ``path``, ``kind``, ``truncated``, ``channels`` (with ``shape`` for MATLAB and HDF5
        variables) or ``can_ids`` (and ``frames`` for CAN logs)."""
        out: dict[str, Any] = {"path": self.path, "kind": self.kind, "truncated": self.truncated}
        if self.kind == "can":
            out["frames"] = self.frames
            out["can_ids"] = [{**asdict(i), "id": i.label} for i in self.can_ids]
        else:
            # a shape only where the format has arrays (MATLAB, HDF5): the other formats' keys stay as they were
            out["channels"] = [_channel_dict(c) for c in self.channels]
        return out


def _channel_dict(channel: ChannelInfo) -> dict[str, Any]:
    """A channel as JSON; ``shape`` only where the format has arrays (MATLAB, HDF5)."""
    return {k: v for k, v in asdict(channel).items() if k != "shape" or v is not None}
