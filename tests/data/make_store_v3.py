"""Make ``store_v3.db``: a wear-history store written by online-backlash at schema version 3.

Run once with the code of commit 3372d26 (main before issue 28, schema 3), from the repository
root: ``python tests/data/make_store_v3.py``. The store is committed as it came out, so that
``tests/test_wear_clock.py`` opens a store made by the old code, not one rebuilt by the new.
Four daily 20 s logs of the simulated rig (``online_backlash.rig.simulate_rig``), placed by
``--start``, tracked by ``online-backlash track`` with a limit and a warning level.
"""

import datetime as dt
import os
import tempfile
from pathlib import Path

from online_backlash.cli import main
from online_backlash.rig import simulate_rig

OUT = Path(__file__).resolve().parent / "store_v3.db"
START = dt.datetime(2026, 3, 2, 8, 0, tzinfo=dt.timezone.utc)


def make() -> None:
    if OUT.exists():
        OUT.unlink()
    with tempfile.TemporaryDirectory() as folder:
        for day in range(4):
            rec = simulate_rig(duration_s=20.0, play_deg=0.30 + 0.01 * day, seed=100 + day)
            log = os.path.join(folder, f"day{day}.csv")
            rec.write_csv(log)
            start = (START + dt.timedelta(days=day)).isoformat()
            argv = ["track", log, "--ratio", "30", "--db", str(OUT), "--gearbox", "old-gb", "--every", "5"]
            argv += ["--start", start, "--limit-arcmin", "21", "--warn-arcmin", "19", "--quiet"]
            assert main(argv) == 0
    for suffix in ("-wal", "-shm"):
        assert not Path(f"{OUT}{suffix}").exists()


if __name__ == "__main__":
    make()
