"""The fleet's progress bar: gearboxes done of the total, samples per second (tqdm, on stderr)."""

from __future__ import annotations

import time
from types import TracebackType

from tqdm import tqdm

from .runner import GearboxOutcome


class FleetProgress:
    """A progress bar over a fleet's gearboxes, fed with :meth:`done` as each one finishes.

    Samples per second are the samples fed by the finished gearboxes over the wall-clock time
    since the bar started. ``show=False`` (``--json``, ``--quiet``, stderr not a terminal)
    draws nothing but still counts.
    """

    def __init__(self, total: int, show: bool) -> None:
        self.total = total
        self.samples = 0
        self._started = time.perf_counter()
        self._bar = tqdm(total=total, desc="fleet", unit=" gearbox", disable=not show, leave=False)

    @property
    def samples_per_s(self) -> float:
        """Samples fed by the finished gearboxes per wall-clock second."""
        elapsed = time.perf_counter() - self._started
        return self.samples / elapsed if elapsed > 0 else 0.0

    def done(self, outcome: GearboxOutcome) -> None:
        """One gearbox finished (or failed)."""
        self.samples += outcome.samples_fed
        self._bar.update(1)
        self._bar.set_postfix_str(f"{self.samples_per_s:,.0f} samples/s")

    def __enter__(self) -> FleetProgress:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self._bar.close()
