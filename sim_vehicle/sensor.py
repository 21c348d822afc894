"""The simulated vehicle's sensor and its GNSS: what it reads, and where it thinks it is.

Three imperfections, each off by default (a perfect sensor at a perfectly known place):

* **noise**: white Gaussian noise of standard deviation ``noise_std`` (field units) added
  to every reading;
* **lag**: the sensing element responds as a first-order system with time constant
  ``lag_s``: ``lag_s * dy/dt = g(p(t)) - y`` where ``g`` is the field and ``p`` the true
  position (a metal-oxide gas sensor: seconds). The noise is added to ``y`` (it is the
  read-out's, not the air's);
* **position error**: the GNSS error ``e`` is a first-order Gauss-Markov process per axis,
  stationary standard deviation ``position_std_m`` and correlation time
  ``position_tau_s`` (a standalone receiver: metres, correlated over tens of seconds).

Where the vehicle is, and where it believes it is
--------------------------------------------------
An autopilot flies on its own estimate of its position. Its velocity estimate is good
(GNSS Doppler and the IMU give centimetres per second), its position estimate carries the
slowly wandering GNSS error. So the body's motion is the integral of the velocity it flies
-- the true path, smooth, whose length is the odometer -- and everything the vehicle does
with a position (arrive at a waypoint, keep inside the fence and the area, fit the field's
gradient along a trace, report GLOBAL_POSITION_INT and the position of each sample) uses
the *believed* position ``p + e``. The onboard tracer therefore flies its believed position,
as a real one would: it has nothing else. It ends a waypoint where its GNSS says the
waypoint is, and traces the iso-line that its (lagged, noisy) readings place at its
believed positions.

The body's record holds the believed position; each tick the change of ``e`` is added to
it beside the kinematic step (not through the velocity: the odometer counts only what was
flown), and the field is read at the true position ``record - e``.

Discretisation
--------------
The field is read once per tick (period ``h``); between readings the air along the track is
taken as linear in time (first-order hold), for which the exact response of the first-order
sensor is::

    y_k = phi * y_{k-1} + (1 - phi) * g_{k-1} + (g_k - g_{k-1}) * (1 - lag_s * (1 - phi) / h)

with ``phi = exp(-h / lag_s)``: exact on a ramp (a constant-speed flight through a
constant gradient lags by exactly ``lag_s``). The sensor starts settled (``y = g`` at its
first reading). The Gauss-Markov process is exact at the tick times:
``e_k = a * e_{k-1} + position_std_m * sqrt(1 - a**2) * w_k`` with ``a = exp(-h / tau)``,
``w_k`` standard normal, ``e_0`` drawn from the stationary distribution.

Random numbers are drawn ahead in rows of three per tick (:meth:`SimBody.noise_ahead`):
the reading's noise (already scaled) and the two axes' innovations. The functions here are
compiled (numba) and called by the tracer's machine each tick, and by :class:`SimBody` for
the ticks it takes itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

SENSOR = np.dtype([
    # the model, per tick of the body that owns it
    ("lag_s", "f8"), ("lag_phi", "f8"), ("lag_c", "f8"),
    ("pos_std_m", "f8"), ("pos_phi", "f8"), ("pos_gain_m", "f8"),
    # state: the sensing element's reading and the air it last saw; the GNSS error
    ("has_y", "i8"), ("y", "f8"), ("g_prev", "f8"),
    ("has_e", "i8"), ("ex_m", "f8"), ("ey_m", "f8"),
])
"""One sensor's model and state (one record, shared by Python and compiled code)."""

_STATE_FIELDS = ("has_y", "y", "g_prev", "has_e", "ex_m", "ey_m")


@dataclass(frozen=True)
class SensorModel:
    """How a vehicle's sensor and GNSS differ from perfect (all zero: perfect).

    Parameters
    ----------
    noise_std
        Standard deviation of the white Gaussian noise on each reading (field units).
    lag_s
        Time constant of the first-order response (s); 0: instantaneous.
    position_std_m
        Stationary standard deviation of the GNSS error, per axis (m); 0: exact.
    position_tau_s
        Correlation time of the GNSS error (s).
    """

    noise_std: float = 0.0
    lag_s: float = 0.0
    position_std_m: float = 0.0
    position_tau_s: float = 10.0

    def __post_init__(self) -> None:
        for name in ("noise_std", "lag_s", "position_std_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be >= 0, got {v!r}")
        if not (math.isfinite(self.position_tau_s) and self.position_tau_s > 0.0):
            raise ValueError(f"position_tau_s must be > 0, got {self.position_tau_s!r}")

    @property
    def stochastic(self) -> bool:
        """Random numbers are needed (noise or a position error)."""
        return self.noise_std > 0.0 or self.position_std_m > 0.0

    def record(self, dt_s: float) -> np.ndarray:
        """A fresh one-record :data:`SENSOR` array for ticks of ``dt_s`` (nothing sensed
        yet)."""
        r = np.zeros(1, dtype=SENSOR)
        s = r[0]
        s["lag_s"] = self.lag_s
        if self.lag_s > 0.0:
            phi = math.exp(-dt_s / self.lag_s)
            s["lag_phi"] = phi
            s["lag_c"] = 1.0 - self.lag_s * (1.0 - phi) / dt_s
        s["pos_std_m"] = self.position_std_m
        a = math.exp(-dt_s / self.position_tau_s)
        s["pos_phi"] = a
        s["pos_gain_m"] = self.position_std_m * math.sqrt(1.0 - a * a)
        return r


def carry_state(new: np.ndarray, old: np.ndarray) -> None:
    """Give the sensor record ``new`` the state (reading, GNSS error) of ``old``: the same
    sensor on a body rebuilt with other settings."""
    for name in _STATE_FIELDS:
        new[0][name] = old[0][name]


def state_of(record: np.ndarray) -> dict[str, float]:
    """The state of a sensor record, JSON-safe (:func:`restore_state` puts it back)."""
    return {name: record[0][name].item() for name in _STATE_FIELDS}


def restore_state(record: np.ndarray, state: dict[str, float]) -> None:
    for name in _STATE_FIELDS:
        record[0][name] = state[name]


@njit(cache=True)
def gnss_step(sn, b, noise: np.ndarray, k: int) -> None:
    """Advance the GNSS error of sensor record ``sn`` by one tick (innovations in row ``k``
    of ``noise``) and move the believed position in body record ``b`` with it."""
    if sn.pos_std_m > 0.0 and k < noise.shape[0]:
        if sn.has_e:
            ex = sn.pos_phi * sn.ex_m + sn.pos_gain_m * noise[k, 1]
            ey = sn.pos_phi * sn.ey_m + sn.pos_gain_m * noise[k, 2]
        else:  # the first fix: from the stationary distribution
            ex = sn.pos_std_m * noise[k, 1]
            ey = sn.pos_std_m * noise[k, 2]
            sn.has_e = 1
    elif sn.pos_std_m <= 0.0 and (sn.ex_m != 0.0 or sn.ey_m != 0.0):
        ex = 0.0  # the error was switched off: the estimate is exact again
        ey = 0.0
        sn.has_e = 0
    else:
        return
    b.x_m += ex - sn.ex_m
    b.y_m += ey - sn.ey_m
    sn.ex_m = ex
    sn.ey_m = ey


@njit(cache=True)
def sensed_value(sn, g: float, noise: np.ndarray, k: int) -> float:
    """The reading of sensor ``sn`` this tick, where the air at the true position holds
    ``g``: its lagged response plus the read-out noise in row ``k`` of ``noise``."""
    y = g
    if sn.lag_s > 0.0:
        if sn.has_y:
            y = sn.lag_phi * sn.y + (1.0 - sn.lag_phi) * sn.g_prev + (g - sn.g_prev) * sn.lag_c
        sn.has_y = 1
        sn.y = y
        sn.g_prev = g
    else:
        sn.has_y = 0
    if k < noise.shape[0]:
        y += noise[k, 0]
    return y
