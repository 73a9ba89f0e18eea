"""The fleet: many gearboxes tracked from one manifest, in parallel on Dask (``track --manifest``).

* :mod:`.manifest`: the TOML manifest (``[defaults]``, one ``[[gearbox]]`` table per gearbox,
  every key a ``track`` option) -> one :class:`GearboxJob` per gearbox, each checked by
  ``track``'s own option parser (handed in by the CLI; the library never imports it).
* :mod:`.runner`: :func:`run_fleet`, one task per gearbox on a Dask ``LocalCluster``, an
  existing scheduler, or serially in this process; a task killed with its worker is retried and
  resumes from the store's checkpoint.
* :mod:`.progress`: the fleet's progress bar (gearboxes done, samples/s).
"""

from .manifest import GearboxJob, ManifestError, load_manifest
from .runner import GearboxOutcome, run_fleet

__all__ = ["GearboxJob", "GearboxOutcome", "ManifestError", "load_manifest", "run_fleet"]
