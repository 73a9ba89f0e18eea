"""Make the recording bundled for ``online-backlash demo``.

A synthetic 30:1 gearbox with 0.50 deg of play (load side; 0.20 deg on the left flank, 0.30 deg on
the right), driven in continuous rotation with reversals every 2-6 s at about 30 deg/s (load side),
sampled at 1 kHz for 60 s by a 14-bit motor encoder and a 17-bit load encoder with 2 counts of
Gaussian noise, written as encoder counts. Run from the repository root:

    python scripts/make_demo_log.py

It writes ``src/online_backlash/data/demo_rig_30to1.csv.gz`` (deterministic: seed 2026).
"""

from pathlib import Path

from online_backlash.simulation.rig import simulate_rig

DEMO = dict(duration_s=60.0, ratio=30.0, play_deg=0.5, left_fraction=0.4, noise_counts=2.0, seed=2026)

if __name__ == "__main__":
    out = Path(__file__).resolve().parents[1] / "src" / "online_backlash" / "data" / "demo_rig_30to1.csv.gz"
    simulate_rig(**DEMO).write_csv(out, units="counts")
    print(f"wrote {out}")
