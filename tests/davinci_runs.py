"""The measured da Vinci gearhead runs beside the checkout (``../shared``, read-only; ODbL v1.0, see their README)
and how they are read, stated once for the tests: the README's call (ratio -35, encoder counts)."""

from __future__ import annotations

from pathlib import Path

#: The folder of the measured runs (``tool4_L_run00_0.1Hz_torque10pct.csv``, run20, run49; ``sweep/``).
DAVINCI = Path(__file__).resolve().parents[2] / "shared" / "data" / "davinci_tool_gearhead_backlash"
#: ``--columns`` of a run with its torque column (N m behind the flanks).
WITH_TORQUE = "time=time_s,motor=motor_counts,load=spindle_counts,torque=backend_torque_Nm"
#: ``--columns`` of a run without it (the kinematic play alone).
WITHOUT_TORQUE = "time=time_s,motor=motor_counts,load=spindle_counts"
#: The options that read a run, but its ``--columns``: motor:load -35, 4096 and 8192 counts per revolution.
UNITS = ["--ratio", "-35", "--units", "counts", "--motor-cpr", "4096", "--load-cpr", "8192"]
#: The same run read by a reader (``read_csv_arrays``, ``CsvLog``): the keyword arguments, without the torque column.
READ = {
    "columns": {"time": "time_s", "motor": "motor_counts", "load": "spindle_counts"},
    "units": "counts",
    "motor_cpr": 4096,
    "load_cpr": 8192,
}
