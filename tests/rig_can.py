"""The command-line options of the simulated rig's CAN frames (``simulation.rig_logs.rig_can_frames``), stated once
for the tests: the bundled database ``rig`` and the two signals that carry the angles."""

from __future__ import annotations

#: ``--dbc rig`` and the motor's and the load's signals.
RIG_CAN = ["--dbc", "rig", "--motor-signal", "MotorAngle.Count", "--load-signal", "LoadAngle.Count"]
