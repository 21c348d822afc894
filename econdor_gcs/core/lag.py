"""The station's correction for a sensor that lags: each sample's value where it was taken.

A first-order sensor with time constant ``tau`` (``lag_s``) reads ``y`` with
``tau * dy/dt = g(p(t)) - y``, where ``g`` is the field and ``p(t)`` the vehicle's track: a
reading is a blend of what the sensor passed over in the last few ``tau``. At 8 m/s and
``tau = 1`` s a feature shows up 8 m late along the track, on a lawnmower opposite ways on
neighbouring legs, and a narrow one is smeared over tens of metres. Knowing ``tau``, the
station undoes it along each vehicle's track.

The correction (:class:`LagCorrection` ``deconvolve``) inverts the sensor's equation:
``g = y + tau * dy/dt`` at each sample, its own position kept. The derivative is a local
polynomial fit of the readings against time whose window is chosen per sample by the
intersection-of-confidence-intervals rule (Katkovnik, "A new method for varying adaptive
bandwidth selection", IEEE Trans. Signal Process. 47(9), 1999; Lepski's method): of a ladder
of estimates -- a cubic through five samples, then straight lines over 1 to 32 samples each
side -- the widest whose slope still agrees with every narrower one within ``ICI_GAMMA``
standard errors. Where the readings are clean or change fast it stays narrow (the exact
inverse up to the sampling), where noise dominates it widens, so the correction does not
multiply the noise by ``tau / dt``. The noise level it needs is estimated from the readings
themselves (:func:`noise_std`: the lagged signal is smooth at the sample rate, the read-out
noise is not).

The other classic correction, moving each reading to where the vehicle was ``tau`` earlier
(the first moment of the response), is not offered: it leaves the smear (the response's
spread is ``tau`` as well), and a flight shorter than ``tau`` -- threshold mode's first
steps are 5 m -- piles all its samples onto the point it started from.

When the lag is not known it is estimated from the samples (:func:`estimate_lag`) by
crossover analysis, as airborne surveys calibrate a sensor's lag: where the vehicle passes
the same place twice (within ``CROSSOVER_M``, at least ``CROSSOVER_GAP_S`` apart), the two
readings must agree once corrected. As ``g = y + tau * dy/dt`` is linear in ``tau``, the
``tau`` that makes them agree best in least squares is a closed form over all pairs:
``tau = -sum(dy * dd) / (sum(dd * dd) - sum(var dd))``, ``dy`` and ``dd`` the pair's
differences of reading and of its rate of change, ``var dd`` the part of the latter's
square the read-out noise accounts for (left in, it would pull the estimate toward 0). A
lag shifts a feature along the track, so passes in different directions over a slope say
the most; passes over flat ground, or the same way over it, say nothing, and a flight
without crossovers over a slope gives no estimate.

Samples are corrected per vehicle, in time order, within stretches of continuous sampling
(a pause longer than ``GAP_S`` -- a hover between flights -- starts a new stretch; the
sensor settles while the vehicle hovers, so a stretch starts from a settled reading).
Samples of different vehicles never mix. This is pure numerics: the caller (the DFC) says
when and on what.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from .geometry import FloatArray
from .tasks import SampleLog, Task, TraceTask

GAP_S = 1.0
"""A pause in a vehicle's samples longer than this (and than 5 sample periods) separates
two stretches of its track."""

ICI_GAMMA = 2.5
"""Half-width of the confidence intervals of the window rule, in standard errors."""

LADDER = (1, 2, 3, 4, 6, 8, 11, 16, 22, 32)
"""The derivative's window half-widths tried, in samples (each side)."""


class LagCorrection(StrEnum):
    """How the station undoes the sensor's lag (see the module docstring): ``deconvolve``
    with the lag it is told, ``estimate`` with the lag it estimates from its samples
    (:func:`estimate_lag`), ``none`` not at all."""

    DECONVOLVE = "deconvolve"
    ESTIMATE = "estimate"
    NONE = "none"


def told_lag(correction: str, lag_s: float | None) -> tuple[float, bool] | None:
    """The sensor lag the onboard tracer is to trace with, as ``(sensor_lag_s,
    lag_unknown)``, for a station that corrects its samples the ``correction`` way for
    ``lag_s`` (s; None or NaN: no usable estimate yet). With an estimated lag, the estimate,
    0 included (a tracer told of an unknown lag before is told it is known now), or with
    none yet a lag of unknown size (``(0.0, True)``: the tracer's filter is set for a lag,
    compensating none); otherwise the lag corrected for, and None when that is none (the
    tracer keeps its own setting).

    >>> told_lag(LagCorrection.ESTIMATE, 0.0), told_lag(LagCorrection.ESTIMATE, None)
    ((0.0, False), (0.0, True))
    >>> told_lag(LagCorrection.DECONVOLVE, 1.0), told_lag(LagCorrection.NONE, 0.0)
    ((1.0, False), None)
    """
    usable = lag_s is not None and math.isfinite(lag_s)
    if correction == LagCorrection.ESTIMATE:
        return (float(lag_s), False) if usable and lag_s is not None else (0.0, True)
    return (float(lag_s), False) if usable and lag_s is not None and lag_s > 0.0 else None


def tell_lag(plans: list[list[Task]], told: tuple[float, bool] | None) -> list[list[Task]]:
    """``plans`` with every trace task carrying ``told`` (:func:`told_lag`); as they are
    when that is None."""
    if told is None:
        return plans
    lag, unknown = told
    return [[dataclasses.replace(t, sensor_lag_s=lag, lag_unknown=unknown)
             if isinstance(t, TraceTask) else t for t in plan] for plan in plans]


NOISE_DIFFERENCE = 4
"""The order of the differences the read-out noise is estimated from."""


def noise_std(*stretches: FloatArray) -> float:
    """A robust estimate of the white read-out noise in stretches of readings sampled
    evenly: the median absolute fourth difference over ``0.6745 * sqrt(70)``.

    Differences of white noise keep it (the fourth's variance is ``70 sigma^2``) while a
    smooth signal's shrink with each order by the sample period -- and a lagged sensor's
    signal is smooth at the sample rate. Second differences would still count the
    curvature of a broad field as noise; the median ignores the few samples where the
    signal turns fast.

    >>> rng = np.random.default_rng(0)
    >>> t = np.linspace(0, 400, 4000)
    >>> round(noise_std(30 * np.sin(t / 5) + rng.normal(0, 2.0, 4000)), 1)
    2.0
    >>> noise_std(30 * np.sin(t / 5)) < 1e-3
    True
    """
    k = NOISE_DIFFERENCE
    d = np.concatenate([np.diff(np.asarray(v, dtype=float), n=k) for v in stretches
                        if len(v) > k] or [np.zeros(0)])
    if len(d) == 0:
        return 0.0
    return float(np.median(np.abs(d)) / (0.6745 * math.sqrt(math.comb(2 * k, k))))


def _cubic_slopes(t: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The slope at every sample of the cubic through it and its four nearest neighbours
    in order (two each side; at the ends the five first or last), and its standard error
    per unit noise: the narrowest, least biased estimate of the ladder."""
    n = len(t)
    k = min(5, n)
    first = np.clip(np.arange(n) - 2, 0, n - k)
    idx = first[:, None] + np.arange(k)[None, :]
    dt = t[idx] - t[:, None]
    deg = min(3, k - 1)
    v = dt[:, :, None] ** np.arange(deg + 1)[None, None, :]  # (n, k, deg + 1)
    # scaled by the window's duration: the normal equations stay well conditioned
    span = np.maximum(np.abs(dt).max(axis=1), 1e-12)
    v = v / span[:, None, None] ** np.arange(deg + 1)[None, None, :]
    gram = np.einsum("nki,nkj->nij", v, v)
    inv = np.linalg.pinv(gram)  # repeated times leave it singular: least norm, no error
    coef = np.einsum("nij,nkj,nk->ni", inv, v, y[idx])
    return coef[:, 1] / span, np.sqrt(inv[:, 1, 1]) / span


def _slopes(t: FloatArray, y: FloatArray, ladder: tuple[int, ...]
            ) -> tuple[list[FloatArray], list[FloatArray]]:
    """The ladder of slope estimates at every sample, narrowest first, with their standard
    errors per unit noise: the local cubic of :func:`_cubic_slopes`, then per half-width
    ``h`` of ``ladder`` the local linear fit over the samples at most ``h`` away (fewer at
    the ends; standard error ``1 / sqrt(S_tt)``). Sums are over times relative to the
    centre sample."""
    n = len(t)
    s0 = np.ones(n)
    s1 = np.zeros(n)
    s2 = np.zeros(n)
    sy = y.copy()
    sty = np.zeros(n)
    cubic, cubic_scale = _cubic_slopes(t, y) if n >= 3 else (np.zeros(n), np.full(n, np.inf))
    slopes, scales = [cubic], [cubic_scale]
    done = 0
    for h in ladder:
        for o in range(done + 1, min(h, n - 1) + 1):
            for sign in (1, -1):
                if sign > 0:  # neighbour j = i + o, for i < n - o
                    ctr, nb = slice(0, n - o), slice(o, n)
                else:         # neighbour j = i - o, for i >= o
                    ctr, nb = slice(o, n), slice(0, n - o)
                dt = t[nb] - t[ctr]
                s0[ctr] += 1.0
                s1[ctr] += dt
                s2[ctr] += dt * dt
                sy[ctr] += y[nb]
                sty[ctr] += dt * y[nb]
        done = max(done, min(h, n - 1))
        stt = s2 - s1 * s1 / s0
        ok = stt > 0.0
        slope = np.zeros(n)
        slope[ok] = (sty[ok] - s1[ok] * sy[ok] / s0[ok]) / stt[ok]
        scale = np.full(n, np.inf)
        scale[ok] = 1.0 / np.sqrt(stt[ok])
        slopes.append(slope)
        scales.append(scale)
    return slopes, scales


def track_derivative(t_s: FloatArray, values: FloatArray, noise: float,
                     ladder: tuple[int, ...] = LADDER, gamma: float = ICI_GAMMA) -> FloatArray:
    """``dy/dt`` along one stretch of a track, each sample with its own window (the
    intersection-of-confidence-intervals rule: the widest window of ``ladder`` whose slope
    interval, ``+- gamma`` standard errors for read-out noise ``noise``, still meets every
    narrower one's).

    >>> t = np.arange(0.0, 5.0, 0.1)
    >>> d = track_derivative(t, 3.0 * t ** 2, noise=0.0)
    >>> bool(np.allclose(d[1:-1], 6.0 * t[1:-1]))
    True
    """
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(values, dtype=float)
    if len(t) < 2:
        return np.zeros(len(t))
    slopes, scales = _slopes(t, y, ladder)
    out = slopes[0].copy()
    lo = np.full(len(t), -np.inf)
    hi = np.full(len(t), np.inf)
    alive = np.ones(len(t), dtype=bool)
    for slope, scale in zip(slopes, scales, strict=True):
        half = np.where(np.isfinite(scale), gamma * noise * scale, np.inf)
        lo = np.maximum(lo, slope - half)
        hi = np.minimum(hi, slope + half)
        alive &= lo <= hi
        if not alive.any():
            break
        out[alive] = slope[alive]
    return out


def _stretches(t_s: FloatArray) -> list[slice]:
    """Index ranges of continuous sampling in time-ordered ``t_s``."""
    if len(t_s) == 0:
        return []
    dt = np.diff(t_s)
    period = float(np.median(dt)) if len(dt) else 0.0
    gap = max(GAP_S, 5.0 * period)
    cuts = np.flatnonzero(dt > gap) + 1
    edges = [0, *cuts.tolist(), len(t_s)]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def _track_stretches(samples: SampleLog) -> Iterator[tuple[NDArray[np.intp], float]]:
    """Each vehicle's stretches of continuous sampling (:func:`_stretches`), as the indices
    of their samples in time order, with that vehicle's read-out noise (:func:`noise_std`
    over all its stretches)."""
    for v in np.unique(samples.vehicle):
        idx = np.flatnonzero(samples.vehicle == v)
        idx = idx[np.argsort(samples.t_s[idx], kind="stable")]
        stretches = [idx[s] for s in _stretches(samples.t_s[idx])]
        sigma = noise_std(*(samples.value[k] for k in stretches))
        for k in stretches:
            yield k, sigma


def correct_lag(samples: SampleLog, lag_s: float,
                method: LagCorrection = LagCorrection.DECONVOLVE) -> SampleLog:
    """``samples`` with the sensor's lag ``lag_s`` undone (a new log, in the same order).

    Parameters
    ----------
    samples
        Readings of one or more vehicles (``vehicle`` and ``t_s`` tell their tracks apart
        and order them).
    lag_s
        The sensor's time constant (s); 0 returns the samples unchanged.
    method
        :class:`LagCorrection`: ``deconvolve`` corrects the values (the positions are
        kept), ``none`` nothing.

    Returns
    -------
    SampleLog
        The corrected samples.

    Examples
    --------
    A sensor with a 1 s lag flown at 8 m/s through a field rising 2 per metre reads 16 low;
    corrected, it reads the field:

    >>> t = np.arange(0.0, 10.0, 0.1)
    >>> x = 8.0 * t
    >>> log = SampleLog(t, x, np.zeros_like(t), 2.0 * x - 16.0,
    ...                 np.zeros(len(t), dtype=np.int8), np.zeros(len(t), dtype=np.int16))
    >>> fixed = correct_lag(log, 1.0)
    >>> bool(np.allclose(fixed.value, 2.0 * x))
    True
    """
    method = LagCorrection(method)
    if not (math.isfinite(lag_s) and lag_s >= 0.0):
        raise ValueError(f"lag_s must be >= 0, got {lag_s!r}")
    out = samples.copy()
    if lag_s == 0.0 or method == LagCorrection.NONE or len(samples) == 0:
        return out
    for k, sigma in _track_stretches(samples):
        d = track_derivative(samples.t_s[k], samples.value[k], sigma)
        out.value[k] = samples.value[k] + lag_s * d
    return out


CROSSOVER_M = 1.0
""":func:`estimate_lag`: two samples this close (m) are a crossover ..."""
CROSSOVER_GAP_S = 3.0
"""... when taken at least this long apart (or by different vehicles)."""
RATE_HALF_WINDOW_S = 0.5
""":func:`estimate_lag` reads each sample's value and rate of change off a straight line
fitted to the readings within this long of it along the track: one window for all, so
that every pair compares alike (the ICI window of :func:`track_derivative` is chosen per
sample, and a noisy rate attenuates the estimate)."""
MIN_CROSSOVERS = 30
"""Fewer crossovers than this give no estimate."""
SIGNAL_SHARE = 0.5
"""Nor do crossovers whose differences of rate are less than this share signal (the rest
being the read-out noise's)."""


@dataclass(frozen=True)
class LagEstimate:
    """What :func:`estimate_lag` returns.

    Attributes
    ----------
    lag_s : float
        The estimated time constant (s, >= 0); NaN when the samples cannot tell.
    stderr_s : float
        Its standard error (s; from the pairs' residuals, which are not all independent:
        a lower bound); NaN with no estimate.
    crossovers : int
        The pairs of samples it rests on.
    """

    lag_s: float
    stderr_s: float
    crossovers: int

    @property
    def usable(self) -> bool:
        """Whether the estimate is firm enough to correct with: within 0.05 s + 10 %."""
        return bool(math.isfinite(self.lag_s) and self.stderr_s <= 0.05 + 0.1 * self.lag_s)


def _line_fits(t: FloatArray, y: FloatArray, half_s: float
               ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Value and slope at each sample of the straight line fitted to the readings within
    ``half_s`` of it in time (one stretch, sorted by time), and the slope's variance per
    unit of read-out noise variance (``1 / sum (t - mean t)^2``; inf where none)."""
    n = len(t)
    if n < 3:
        return y.copy(), np.zeros(n), np.full(n, np.inf)
    tc = t - t[0]
    lo = np.searchsorted(tc, tc - half_s, side="left")
    hi = np.searchsorted(tc, tc + half_s, side="right")
    c = [np.concatenate(([0.0], np.cumsum(a))) for a in (np.ones(n), tc, tc * tc, y, tc * y)]
    s0, s1, s2, sy, sty = (a[hi] - a[lo] for a in c)
    det = s0 * s2 - s1 * s1
    ok = (hi - lo >= 3) & (det > 1e-9 * np.maximum(s0 * s2, 1e-300))
    slope = np.divide(s0 * sty - s1 * sy, det, out=np.zeros(n), where=ok)
    value = np.where(ok, (sy - slope * s1) / np.maximum(s0, 1.0) + slope * tc, y)
    per_var = np.divide(s0, det, out=np.full(n, np.inf), where=ok)
    return value, slope, per_var


def estimate_lag(samples: SampleLog, crossover_m: float = CROSSOVER_M,
                 gap_s: float = CROSSOVER_GAP_S, half_window_s: float = RATE_HALF_WINDOW_S
                 ) -> LagEstimate:
    """The sensor's first-order time constant estimated from the samples' crossovers
    (module docstring).

    Parameters
    ----------
    samples
        Raw readings (not corrected) of one or more vehicles.
    crossover_m, gap_s, half_window_s
        ``CROSSOVER_M``, ``CROSSOVER_GAP_S``, ``RATE_HALF_WINDOW_S``.

    Returns
    -------
    LagEstimate

    Examples
    --------
    A sensor with a 0.8 s lag flown east, then back west 0.5 m to the north, over a field
    rising 2 per metre eastward:

    >>> t = np.arange(0.0, 12.5, 0.1)
    >>> x = np.concatenate((8.0 * t, 100.0 - 8.0 * t))
    >>> y = np.concatenate((np.zeros_like(t), np.full_like(t, 0.5)))
    >>> read = np.concatenate((2.0 * x[:125] - 2.0 * 8.0 * 0.8, 2.0 * x[125:] + 2.0 * 8.0 * 0.8))
    >>> log = SampleLog(np.concatenate((t, t + 13.0)), x, y, read,
    ...                 np.zeros(250, dtype=np.int8), np.zeros(250, dtype=np.int16))
    >>> round(estimate_lag(log).lag_s, 2)
    0.8
    """
    n = len(samples)
    if n < 2:
        return LagEstimate(math.nan, math.nan, 0)
    value, rate, rate_var = np.zeros(n), np.zeros(n), np.zeros(n)
    for k, sigma in _track_stretches(samples):
        value[k], rate[k], per_var = _line_fits(samples.t_s[k], samples.value[k],
                                                half_window_s)
        rate_var[k] = sigma * sigma * per_var
    pairs = cKDTree(np.column_stack((samples.x_m, samples.y_m))).query_pairs(
        crossover_m, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    keep = ((np.abs(samples.t_s[i] - samples.t_s[j]) >= gap_s)
            | (samples.vehicle[i] != samples.vehicle[j]))
    i, j = i[keep], j[keep]
    dy, dd = value[i] - value[j], rate[i] - rate[j]
    sxx = float(np.sum(dd * dd))
    # the rates' own noise inflates sum(dd^2) and would pull the estimate toward 0 (errors
    # in variables): taken out; where it is most of it, the crossovers lie on flat ground
    # or were flown the same way, and tell nothing
    signal = sxx - float(np.sum(rate_var[i] + rate_var[j]))
    if len(i) < MIN_CROSSOVERS or not signal >= SIGNAL_SHARE * sxx:
        return LagEstimate(math.nan, math.nan, len(i))
    sxx = signal
    tau = -float(np.sum(dy * dd)) / sxx
    resid = dy + tau * dd
    se = math.sqrt(float(np.sum(dd * dd * resid * resid))) / sxx
    return LagEstimate(max(tau, 0.0), se, len(i))
