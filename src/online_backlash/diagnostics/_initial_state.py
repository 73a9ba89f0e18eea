"""The load's state inside the dead band at the record's start: a nuisance of the base fit.

Eq. (1)-(3) run freely need the output before the first sample, ``x(-1)``; the simulation
residual takes the load at rest there, ``x(-1) = y[0]``. A record can start with the load
moving inside the dead band (a rig that was already turning when the logger started): the real
load coasts on, the model holds it still, and the residual carries one transient until the
motor's flank catches the load. It is not an effect of the gear but the model's unknown
initial condition, and it is treated as system identification treats one (Ljung, *System
Identification: Theory for the User*, 2nd ed., 1999, the initial state of an output-error
model estimated with the parameters; MATLAB's ``InitialState = 'estimate'``): estimated from
the samples it acts on, applied to the residual before and after alike, never claimed as an
effect.

The model of the start. Until the first flank engagement the load rests at its offset ``x0``
(deg, in the frame of the fit: relative to the first measured load angle) until it starts to
move at ``s0`` (s after the first sample; 0: already moving when the record starts; later: a
kick that sets a resting load moving, e.g. a preload released as the motor starts, which is
how the measured run49 starts), then coasts at velocity ``v`` (deg/s), braked by viscous
friction (time constant ``tau``, s, as the coast of :mod:`.dead_band`) and by a constant
(Coulomb) deceleration ``a`` (deg/s^2, opposing ``v``), until it stops at ``s*`` and static
friction holds it::

    x(s) = x0 + v g(s') + a tau (g(s') - s'),   g(s) = tau (1 - exp(-s / tau)),   s' = min(max(s - s0, 0), s* - s0)

with ``s = t - t[0]``; the stop is where the velocity ``(v + a tau) exp(-s / tau) - a tau``
reaches 0, ``v = a tau (exp(s* / tau) - 1)`` (``s* = inf``: still moving when the flank
catches it, ``v`` and ``a`` free). The first engagement is the first sample where the
switching test of eq. (1)-(3) holds against the coasting load (``u >= x / mR + cR`` or
``u <= x / mL - cL``); from that sample on the model is eq. (1)-(3) exactly as before
(:func:`simulate_with_coast`). With no estimated state the coast is empty and the model is the
one of today, starting at rest.

The fit. For every start ``s0`` of a grid (the first sample and up to :data:`MAX_STARTS` samples
before the model at rest engages: a kick after a flank has caught the load is no longer the
initial state), every ``tau`` of a grid (0.5 to 1024 sample periods, a factor of ``sqrt(2)``
apart) and every stop on a grid of the samples before the engagement (and no stop), the
coefficients are fitted by least squares on the samples before the first engagement only, and
the best of them kept; the engagement is recomputed from that fit and the fit repeated until the
engagement stays where it is. Friction brakes the load, it never drives it (``a`` opposes
``v``), and a load still moving :data:`MAX_STRETCH` times as long as the model at rest takes to
engage (plus :data:`MIN_EXTRA` samples) is dropped: a load that runs on with the motor is not
coasting. One that has stopped by then waits in the gap (eq. 7) until a flank catches it, however
long that takes. A load kicked from rest (``s0 > 0``) must have stopped before a flank catches
it: one that starts late and runs on until caught is as much a lag of the load behind the motor
(an effect the loop looks for everywhere) as a kick, and is not taken for the start. Of each
kind (moving from the first sample, kicked later), the start whose model leaves the smallest
simulation residual over the record is kept; the kicked one replaces the other only if it beats
it by the information criterion over the samples either changes (one parameter more), and the
one kept is kept only if it beats the load at rest by an information criterion over the samples
the two models differ on, ``n ln(RSS / RSS_rest) + p ln(n)`` below
:data:`._scoring.BIC_THRESHOLD` (``p = 4`` parameters: ``x0``, ``tau``, ``a`` and ``s*`` or
``v``; ``p = 5`` with ``s0 > 0``). A record that starts at rest, or engaged, has nothing to
estimate and keeps the model of today exactly.

Units: degrees (load side), seconds.
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..model import BacklashParams, simulate_backlash, switching_functions
from ._causal import sample_period_s
from ._scoring import BIC_THRESHOLD

#: viscous time constants of the coast tried, in sample periods
TIME_CONSTANTS = tuple(2.0 ** (j / 2) for j in range(-2, 21))
#: at most this many stops tried per time constant (spread geometrically over the samples before the engagement)
MAX_STOPS = 48
#: fewest samples before the first engagement from which a state is fitted (three coefficients
#: and at least one sample to spare)
MIN_SAMPLES = 4
#: a coast may last at most this many times as long as the model at rest takes to engage (and
#: :data:`MIN_EXTRA` samples more): a load that runs on with the motor for longer is not coasting
MAX_STRETCH = 4
MIN_EXTRA = 64
#: a stop is tried only up to this many time constants after the start (beyond it the velocity
#: before the stop would dwarf the deceleration by ``exp(40)``)
MAX_STOP_TAUS = 40.0
#: at most this many times tried for the load to start moving (spread geometrically over the
#: samples before the model at rest engages; the load moving from the first sample is always tried)
MAX_STARTS = 16
#: parameters of the start: offset, time constant, deceleration, and the stop or the velocity
#: (one more, the time it starts to move, when that is not the first sample)
_N_PARAMS = 4
#: the first window searched for the engagement, samples (grown fourfold until one is found)
_FIRST_WINDOW = 1024


@dataclass(frozen=True)
class Coast:
    """The load's path from the record's start while no flank holds it (see the module docstring).

    ``offset_deg`` (deg): where the load is at the first sample; ``start_s`` (s after the first
    sample): when it starts to move (0: already moving at the first sample; later: at rest until a
    kick sets it moving, e.g. a preload released as the motor starts); ``velocity_deg_s`` (deg/s)
    and ``deceleration_deg_s2`` (deg/s^2) from then on, the viscous ``time_constant_s`` (s), and
    ``stop_s`` (s after the first sample, ``inf``: no stop before the flank catches the load).
    """

    offset_deg: float = 0.0
    velocity_deg_s: float = 0.0
    deceleration_deg_s2: float = 0.0
    time_constant_s: float = float("inf")
    stop_s: float = float("inf")
    start_s: float = 0.0

    def path_deg(self, time_s: np.ndarray) -> np.ndarray:
        """The coasting load angle at ``time_s`` (from the record's first sample), deg."""
        s = np.clip(np.asarray(time_s, dtype=float) - float(time_s[0]), self.start_s, self.stop_s) - self.start_s
        g, h = _shapes(s, self.time_constant_s)
        return self.offset_deg + self.velocity_deg_s * g + self.deceleration_deg_s2 * h


@dataclass(frozen=True)
class InitialState:
    """The load's estimated state inside the dead band at the record's start.

    Attributes
    ----------
    samples : int
        Samples before the first flank engagement the coast acts on (0: nothing estimated, the
        model starts at rest as eq. 1-3 run freely from ``x(-1) = y[0]``).
    coast : Coast
        The fitted coast (offset, velocity, deceleration, time constant, stop).
    rms_at_rest_deg, rms_deg : float
        RMS of the simulation residual over the samples where the two models differ, with the
        load at rest at the start (the model of today) and with this state, deg.
    delta_bic : float
        ``n ln(RSS / RSS_rest) + 4 ln(n)`` over those ``n`` samples (NaN when nothing was fitted).
    path_deg : array
        The coasting load angle from the first sample to the first engagement inclusive
        (``samples + 1`` values, fewer if the record ends first), deg, in the fit's frame.
    """

    samples: int = 0
    coast: Coast = field(default_factory=Coast)
    rms_at_rest_deg: float = 0.0
    rms_deg: float = 0.0
    delta_bic: float = float("nan")
    path_deg: np.ndarray = field(default_factory=lambda: np.empty(0), repr=False)

    @property
    def estimated(self) -> bool:
        """True when a moving start was estimated (the model no longer starts at rest)."""
        return self.samples > 0

    def correction_deg(self, params: BacklashParams, uc_deg: np.ndarray) -> np.ndarray:
        """What the state changes in the output of the model with ``params``, deg: the model with
        this start minus the model at rest (eq. 1-3 from ``x(-1) = 0``), in the fit's frame; zero
        from where the two agree on (a few samples after the first engagement), all zeros when
        nothing was estimated. Subtracted from the load angle, it takes the start out of the
        residual of every fit that runs the model from rest."""
        uc = np.asarray(uc_deg, dtype=float)
        if not self.estimated:
            return np.zeros_like(uc)
        rest = simulate_backlash(uc, params, 0.0)
        x = _until_agreed(uc, params, self.path_deg, rest)
        out = np.zeros_like(uc)
        out[: x.size] = x - rest[: x.size]
        return out

    def coasting(self, start_residual_deg: np.ndarray, residual_deg: np.ndarray) -> np.ndarray:
        """``residual_deg`` (deg) with its first :attr:`samples` values taken from
        ``start_residual_deg``, the simulation residual with this start (:func:`simulate_with_coast`).

        Until a flank first catches the load, the load follows the estimated path and nothing of
        the contact acts on it: not the flank lines of eq. (1), which a joint refit may shift, nor
        the effects, which act through the engaged flank. Those samples' residual is the start's
        own, whatever the model fitted after it (a copy; unchanged when nothing was estimated)."""
        out = np.array(residual_deg, dtype=float)
        out[: self.samples] = np.asarray(start_residual_deg, dtype=float)[: self.samples]
        return out

    def as_dict(self) -> dict[str, Any]:
        """The JSON object ``initial_state`` of ``diagnose --json``."""
        c = self.coast
        return {
            "estimated": self.estimated,
            "samples": self.samples,
            "offset_deg": c.offset_deg,
            "velocity_deg_s": c.velocity_deg_s,
            "deceleration_deg_s2": c.deceleration_deg_s2,
            "time_constant_s": c.time_constant_s if self.estimated else None,
            "stops_after_s": c.stop_s if self.estimated and np.isfinite(c.stop_s) else None,
            "starts_moving_after_s": c.start_s if self.estimated else None,
            "rms_at_rest_deg": self.rms_at_rest_deg,
            "rms_deg": self.rms_deg,
            "delta_bic": self.delta_bic if self.estimated else None,
            "model": "until a flank first engages, the load rests at offset_deg until starts_moving_after_s "
            "(0: moving at "
            "the first sample), then coasts from there at velocity_deg_s, braked by viscous "
            "friction (time_constant_s) and deceleration_deg_s2, and stays where it stops; eq. (1)-(3) from then on. "
            "The model's initial condition, estimated as a nuisance of the base fit and applied to the residual "
            "before and after alike; not an effect",
        }


def _shapes(s: np.ndarray, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """The distance coasted per unit of initial velocity, ``g = tau (1 - exp(-s / tau))`` (s), and
    per unit of deceleration, ``tau (g - s)`` (s^2)."""
    if not np.isfinite(tau):
        return s, -0.5 * s**2
    g = tau * -np.expm1(-s / tau)
    return g, tau * (g - s)


def first_engagement(uc_deg: np.ndarray, load_deg: np.ndarray, params: BacklashParams) -> int:
    """The first sample where a flank catches the load at ``load_deg`` (the switching test of
    eq. 1-3: ``u >= x / mR + cR`` or ``u <= x / mL - cL``); ``len(load_deg)`` if none does."""
    n = min(len(uc_deg), len(load_deg))
    f1, f2 = switching_functions(
        np.asarray(uc_deg[:n], dtype=float), np.asarray(load_deg[:n], dtype=float), params
    )  # eq. (5)-(6)
    hit = (f1 + f2) > 0
    return int(np.argmax(hit)) if hit.any() else n


def simulate_with_coast(
    uc_deg: np.ndarray, params: BacklashParams, path_deg: np.ndarray, x0: float = 0.0
) -> np.ndarray:
    """Eq. (1)-(3) run freely on ``uc_deg``, with the load following ``path_deg`` until a flank first catches it, deg.

    While no flank has engaged, the output is the given path; at the first sample where the
    switching test holds against it (:func:`first_engagement`), eq. (1)-(3) take over with the
    path's value there as ``x(t-1)``. If the path ends first, the load stays at its last value
    (eq. 7 in the dead band). An empty path is the model at rest from ``x(-1) = x0``.
    """
    u = np.asarray(uc_deg, dtype=float)
    path = np.asarray(path_deg, dtype=float)
    if path.size == 0:
        return simulate_backlash(u, params, x0)
    k = first_engagement(u, path, params)
    x = np.empty_like(u)
    x[:k] = path[:k]
    if k < u.size:
        x[k:] = simulate_backlash(u[k:], params, float(path[min(k, path.size - 1)]))
    return x


def _engagement_of(uc: np.ndarray, t: np.ndarray, params: BacklashParams, coast: Coast) -> tuple[int, np.ndarray]:
    """The first engagement of ``coast`` and its path up to it inclusive."""
    n, cap = uc.size, min(uc.size, _FIRST_WINDOW)
    while True:
        path = coast.path_deg(t[:cap])
        k = first_engagement(uc[:cap], path, params)
        if k < cap or cap == n:
            return k, path[: k + 1]
        cap = min(n, 4 * cap)


@functools.lru_cache(maxsize=256)
def _stop_offsets(span: int) -> np.ndarray:
    """Samples after the start at which :func:`_best_coast` tries a stop: at most :data:`MAX_STOPS`,
    spaced geometrically from 1 to ``span`` (read-only; the same spans recur across the search)."""
    out = np.unique(np.round(np.geomspace(1, span, min(MAX_STOPS, span))).astype(int))
    out.flags.writeable = False
    return out


def _best_coast(y: np.ndarray, s_record: np.ndarray, tau: float, start: float = 0.0) -> Coast:
    """The coast with time constant ``tau`` that starts to move at ``start`` (s), closest to ``y``
    at times ``s_record`` (s from the first sample; least squares), over a grid of stops and no stop."""
    k = y.size
    j0 = int(np.searchsorted(s_record, start))  # the first sample at or after the start
    s = np.maximum(s_record - start, 0.0)  # time since the load started to move
    g, h = _shapes(s, tau)
    free = np.column_stack((np.ones(k), g, h))
    coef, *_ = np.linalg.lstsq(free, y, rcond=None)
    if coef[1] * coef[2] < 0:  # friction brakes the load, it does not drive it: viscous only
        coef = np.r_[np.linalg.lstsq(free[:, :2], y, rcond=None)[0], 0.0]
    best = (
        float(np.sum((y - free @ coef) ** 2)),
        Coast(float(coef[0]), float(coef[1]), float(coef[2]), tau, start_s=start),
    )
    # a stop at s[j]: v = a tau (exp(s[j] / tau) - 1), and the path held from there
    if k - 1 - j0 < 1:
        return best[1]
    stops = j0 + _stop_offsets(k - 1 - j0)
    stops = stops[(s[stops] > 0) & (s[stops] <= MAX_STOP_TAUS * tau)]
    if stops.size == 0:
        return best[1]
    gs, hs = _shapes(np.minimum(s[None, :], s[stops, None]), tau)
    per_a = tau * np.expm1(s[stops] / tau)[:, None] * gs + hs  # path per unit of deceleration, one row per stop
    dc = per_a - per_a.mean(axis=1, keepdims=True)
    dy = y - y.mean()
    var = np.sum(dc**2, axis=1)
    a = np.divide(dc @ dy, var, out=np.zeros_like(var), where=var > 0)
    rss = float(np.sum(dy**2)) - a * (dc @ dy)
    j = int(np.argmin(rss))
    if rss[j] < best[0]:
        offset = float(y.mean() - a[j] * per_a[j].mean())
        stop = float(s[stops[j]])
        best = (
            float(rss[j]),
            Coast(offset, float(a[j] * tau * np.expm1(stop / tau)), float(a[j]), tau, stop + start, start),
        )
    return best[1]


def _fit_for(
    uc: np.ndarray, yc: np.ndarray, t: np.ndarray, params: BacklashParams, tau: float, k: int, start: float = 0.0
) -> tuple[Coast, int, np.ndarray] | None:
    """The coast that starts to move at ``start`` (s after the first sample) fitted on the samples
    before the first engagement, the engagement recomputed until it stays put (or repeats); None
    when fewer than :data:`MIN_SAMPLES` remain or the load would run on with the motor."""
    seen: set[int] = set()
    found = None
    longest = max(MAX_STRETCH * k, k + MIN_EXTRA)
    while k >= MIN_SAMPLES and k not in seen:
        seen.add(k)
        coast = _best_coast(yc[:k], t[:k] - t[0], tau, start)  # time from the first sample, s
        k, path = _engagement_of(uc, t, params, coast)
        # a load still moving long after the model at rest engages runs on with the motor: not a
        # coast; one that has stopped waits in the gap (eq. 7) until a flank catches it
        if k > longest and not coast.stop_s <= t[min(longest, t.size - 1)] - t[0]:
            return None
        found = (coast, k, path)
    return found


def _until_agreed(uc: np.ndarray, params: BacklashParams, path: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """The model with the coast :func:`simulate_with_coast` over the first samples, up to one where
    it agrees with the model at rest ``rest`` (eq. 1-3 from equal outputs give equal outputs, so
    the two agree from there to the end), or over the whole record."""
    n, cap = uc.size, min(uc.size, max(4 * path.size, _FIRST_WINDOW))
    while True:
        x = simulate_with_coast(uc[:cap], params, path)
        if cap == n or x[-1] == rest[cap - 1]:
            return x
        cap = min(n, 4 * cap)


def estimate_initial_state(
    params: BacklashParams, uc_deg: np.ndarray, yc_deg: np.ndarray, time_s: np.ndarray
) -> InitialState:
    """The load's offset and velocity inside the dead band at the record's start (see the module docstring).

    Parameters
    ----------
    params : BacklashParams
        The base fit's backlash parameters (eq. 1), in the frame of ``uc_deg`` and ``yc_deg``.
    uc_deg, yc_deg : array
        The referred motor angle and the load angle in the fit's frame, both 0 at the first
        sample (``VorosBacklash(origin="first")``: minus ``u_ref_`` and ``y_ref_``), deg.
    time_s : array
        Sample times, s, increasing.

    Returns
    -------
    InitialState
        ``samples == 0`` when the record starts at rest or engaged, or when a moving start does
        not beat the load at rest by the information criterion.
    """
    uc, yc, t = (np.asarray(a, dtype=float) for a in (uc_deg, yc_deg, time_s))
    rest = simulate_backlash(uc, params, 0.0)
    k_rest = first_engagement(
        uc, rest, params
    )  # a load held at 0 until the first flank: the engagement of today's model
    if k_rest < MIN_SAMPLES or t.size < 2:
        return InitialState()
    period = sample_period_s(t)
    best: dict[bool, tuple[float, int, InitialState]] = {}  # per kind (moving at the first sample, kicked later)
    starts = np.unique(np.round(np.geomspace(1, k_rest - 1, min(MAX_STARTS, k_rest - 1))).astype(int))
    for j, tau in itertools.product((0, *starts), (period * j for j in TIME_CONSTANTS)):
        found = _fit_for(uc, yc, t, params, tau, k_rest, float(t[j] - t[0]))
        if found is None:
            continue
        coast, k, path = found
        if j > 0 and not np.isfinite(coast.stop_s):  # kicked, never stopped: a lag of the load behind the motor as well
            continue
        x = _until_agreed(uc, params, path, rest)
        differ = np.flatnonzero(x != rest[: x.size])
        if differ.size == 0:
            continue
        n = int(differ[-1]) + 1  # from there on the two models agree
        rss, rss_rest = float(np.sum((yc[:n] - x[:n]) ** 2)), float(np.sum((yc[:n] - rest[:n]) ** 2))
        if rss_rest <= 0.0 or rss >= rss_rest:
            continue
        delta = n * float(np.log(max(rss, 1e-300) / rss_rest)) + (_N_PARAMS + (j > 0)) * float(np.log(n))
        state = InitialState(k, coast, float(np.sqrt(rss_rest / n)), float(np.sqrt(rss / n)), delta, path)
        kind = bool(j > 0)
        if kind not in best or rss - rss_rest < best[kind][0]:  # the change of the whole record's squared error
            best[kind] = (rss - rss_rest, n, state)
    chosen = _simpler_unless_beaten(best.get(False), best.get(True), yc - rest)
    if chosen is None or not chosen.delta_bic < BIC_THRESHOLD:
        return InitialState()
    return chosen


def _simpler_unless_beaten(
    moving: tuple[float, int, InitialState] | None,
    kicked: tuple[float, int, InitialState] | None,
    residual_at_rest: np.ndarray,
) -> InitialState | None:
    """The start moving from the first sample, unless the one kicked later (one parameter more,
    the time it starts to move) beats it by the information criterion over the samples either
    changes, ``N ln(RSS_kicked / RSS_moving) + ln(N) < BIC_THRESHOLD``. Each candidate is (change
    of the record's squared error against the load at rest, deg^2; the samples it changes; the state)."""
    if moving is None or kicked is None:
        one = moving or kicked
        return None if one is None else one[2]
    n = max(moving[1], kicked[1])
    rss_rest = float(np.sum(residual_at_rest[:n] ** 2))
    rss_moving, rss_kicked = rss_rest + moving[0], rss_rest + kicked[0]
    if rss_moving > 0.0 and n * float(np.log(max(rss_kicked, 1e-300) / rss_moving)) + float(np.log(n)) < BIC_THRESHOLD:
        return kicked[2]
    return moving[2]
