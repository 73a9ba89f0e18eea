"""Make ``checkpoint_effects_62ce5a3.json``: a BacklashRLS checkpoint carrying every effect of the library.

Written once with the code of commit 62ce5a3 (main before issue 29, whose effects were looked up by
"module:Class" strings in ``effect_terms.EFFECTS``), from the repository root:
``python tests/data/make_checkpoint_effects.py "online-backlash 62ce5a3" tests/data/checkpoint_effects_62ce5a3.json``
(the simulated rig was then ``online_backlash.simulation.rig``). The file is committed as it came out, so that
``tests/test_effect_registry.py`` loads a checkpoint made by the old code. It holds the state after the
first 30000 samples of a 40 s rig and the play the estimator reached at the end of the record, uninterrupted
and restored from that state (an effect without a stream history, ``dead_band_motion``, restarts on a
restore, so the two differ).
"""

import json
import sys

from online_backlash import BacklashRLS
from online_backlash.diagnostics.dead_band import DeadBandMotion
from online_backlash.diagnostics.effects import Compliance, Delay, Drift, TransmissionError
from online_backlash.diagnostics.flank_profile import FlankProfile
from online_backlash.simulation.rig import simulate_rig

rec = simulate_rig(duration_s=40.0, play_deg=0.5, seed=5)
u, y, t = rec.motor_deg / rec.ratio, rec.load_deg, rec.time_s
effects = [
    TransmissionError(load_orders=(1,), ratio=30.0), Delay(lag_step_samples=2), Compliance(proxy="motion"),
    Drift(degree=1, time_scale_s=60.0), DeadBandMotion(), FlankProfile((0.0, 1.0, 2.0)),
]  # fmt: skip
est = BacklashRLS(effects=effects, warm_start_samples=1000)
half = 30000
est.learn_many(u[:half], y[:half], time_s=t[:half])
state = est.state_dict()
est.learn_many(u[half:], y[half:], time_s=t[half:])
restored = BacklashRLS.from_state(json.loads(json.dumps(state)))  # effects without a stream history restart
restored.learn_many(u[half:], y[half:], time_s=t[half:])
with open(sys.argv[2], "w") as f:
    saved = {"backlash_after_deg": est.backlash_, "backlash_restored_deg": restored.backlash_, "state": state}
    json.dump({"written_by": sys.argv[1], **saved}, f)
