"""The effect registry (issue 29 item 3): the library's effects are listed once, in
``diagnostics.effects.LIBRARY``; the name look-up of a checkpoint (``effect_terms.EFFECTS``,
``effect_class``, ``effect_from_dict``) is built from that list, and ``register_effect`` adds a user's own."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from online_backlash import BacklashRLS
from online_backlash.diagnostics._effect_base import EffectBase
from online_backlash.diagnostics.effects import LIBRARY, VOCABULARY
from online_backlash.effect_terms import EFFECTS, effect_class, effect_from_dict, effect_to_dict, register_effect
from online_backlash.errors import InvalidParameterError
from online_backlash.simulation.rig import simulate_rig

#: a checkpoint carrying all six library effects, written by the code before issue 29
#: (tests/data/make_checkpoint_effects.py)
OLD_CHECKPOINT = Path(__file__).resolve().parent / "data" / "checkpoint_effects_62ce5a3.json"
SPLIT = 30000  # the sample at which that checkpoint was written


def _rig() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rec = simulate_rig(duration_s=40.0, play_deg=0.5, seed=5)
    return rec.motor_deg / rec.ratio, rec.load_deg, rec.time_s


def test_the_library_is_the_registry():
    assert [EFFECTS[name] for name in VOCABULARY] == list(LIBRARY)
    assert all(effect_class(cls.name) is cls for cls in LIBRARY)
    with pytest.raises(InvalidParameterError, match="no effect named 'wobble'"):
        effect_class("wobble")


def test_importing_the_estimators_does_not_import_the_diagnostics():
    code = (
        "import sys; import online_backlash.estimators, online_backlash.effect_terms;"
        "assert 'online_backlash.diagnostics' not in sys.modules, sorted(sys.modules)"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_a_checkpoint_written_before_the_registry_loads_and_continues():
    saved = json.loads(OLD_CHECKPOINT.read_text())
    assert [e["name"] for e in saved["state"]["params"]["effects"]] == list(VOCABULARY)
    u, y, t = _rig()
    restored = BacklashRLS.from_state(saved["state"])
    assert [type(e) for e in restored.effects] == list(LIBRARY)
    restored.learn_many(u[SPLIT:], y[SPLIT:], time_s=t[SPLIT:])
    # what the code that wrote it gave when it restored the same state and learned the rest of the record
    assert restored.backlash_ == pytest.approx(saved["backlash_restored_deg"], rel=1e-9)


class Ripple(EffectBase):
    """A toy effect of a user's: a ripple of the load angle at one spatial frequency of the motor angle (deg)."""

    name = "toy_ripple"

    def __init__(self, cycles_per_deg: float = 0.25) -> None:
        self.cycles_per_deg = cycles_per_deg
        super().__init__()

    @property
    def n_terms(self) -> int:
        return 2

    def _columns(self, u: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        phase = 2.0 * np.pi * self.cycles_per_deg * u
        return np.column_stack([np.sin(phase), np.cos(phase)])


@pytest.fixture
def ripple_registered():
    register_effect(Ripple)
    yield Ripple
    del EFFECTS[Ripple.name]


def test_a_registered_effect_round_trips_through_a_checkpoint(ripple_registered):
    u, y, t = _rig()
    y = y + 0.01 * np.sin(2.0 * np.pi * 0.125 * u)
    whole = BacklashRLS(effects=[Ripple(0.125)], warm_start_samples=1000)
    whole.learn_many(u, y, time_s=t)
    first = BacklashRLS(effects=[Ripple(0.125)], warm_start_samples=1000)
    first.learn_many(u[:SPLIT], y[:SPLIT], time_s=t[:SPLIT])
    saved = json.loads(json.dumps(first.state_dict()))
    assert effect_to_dict(Ripple(0.125)) == {"name": "toy_ripple", "params": {"cycles_per_deg": 0.125}}
    assert saved["params"]["effects"] == [effect_to_dict(Ripple(0.125))]
    resumed = BacklashRLS.from_state(saved)
    assert isinstance(resumed.effects[0], Ripple) and resumed.effects[0].cycles_per_deg == 0.125
    resumed.learn_many(u[SPLIT:], y[SPLIT:], time_s=t[SPLIT:])
    assert resumed.backlash_ == whole.backlash_
    assert isinstance(effect_from_dict({"name": "toy_ripple", "params": {"cycles_per_deg": 0.5}}), Ripple)


def test_an_unregistered_effect_is_named_in_the_error():
    with pytest.raises(InvalidParameterError, match="no effect named 'toy_ripple'"):
        effect_from_dict({"name": "toy_ripple", "params": {"cycles_per_deg": 0.5}})
