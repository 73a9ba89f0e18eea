"""A simulated fleet on disk: rig logs of a few gearboxes and their manifest (for tests, benchmarks, trying it out)."""

from __future__ import annotations

from pathlib import Path

from ..simulation.rig import simulate_rig

#: 2023-11-14 22:13:20 UTC: the simulated logs carry UNIX times from here, one log a day.
START_UNIX_S = 1.7e9
DAY_S = 86400.0


def write_simulated_fleet(
    folder: str | Path, gearboxes: int = 3, logs: int = 2, duration_s: float = 20.0, every_s: float = 5.0
) -> Path:
    """Write ``gearboxes`` x ``logs`` simulated 30:1 rig logs (CSV, 1 kHz, UNIX times, one a day)
    into ``folder/gb<g>/day<k>.csv`` and a manifest ``folder/fleet.toml`` naming them; returns it.

    Gearbox ``g``'s play is ``0.2 + 0.05 g + 0.01 k`` degrees in its log ``k``; estimates every
    ``every_s`` seconds of data, limit 21 arcmin.
    """
    folder = Path(folder)
    tables = []
    for g in range(gearboxes):
        (folder / f"gb{g}").mkdir(parents=True, exist_ok=True)
        for k in range(logs):
            rec = simulate_rig(duration_s=duration_s, play_deg=0.2 + 0.05 * g + 0.01 * k, seed=100 * g + k)
            rec.time_s = rec.time_s + START_UNIX_S + k * DAY_S
            rec.write_csv(folder / f"gb{g}" / f"day{k:02d}.csv")
        tables.append(f'[[gearbox]]\nid = "GB-{g}"\nlogs = "gb{g}/*.csv"\n')
    manifest = folder / "fleet.toml"
    manifest.write_text(f"[defaults]\nratio = 30\nevery = {every_s}\nlimit_arcmin = 21\n\n" + "\n".join(tables))
    return manifest
