"""The learning-error stop rule (paper §III, after eq. 7), and what noisy samples do to it.

The rule: after ``min_iterations``, stop when ``gamma_n = 3 E_n / (E_n + E_{n-1} +
E_{n-2})`` is within ``1 +- lambda`` (the learning error ``E_n``, eq. 3, has levelled off)
and the span of the estimate changed by less than 1 % in the last iteration.

With exact samples ``E_n`` falls towards 0 as the map converges. With noisy ones it
cannot: every flight adds samples whose noise the smoothed estimate averages in, so the
estimate moves near them even where nothing is left to learn about the field, and
``E_n`` levels off at that *noise floor* while the map still improves. Taken as it is, a
learning error sitting on its floor reads as "levelled off" (``gamma`` about 1) whatever
the field still has to teach: the rule would fire on the noise. So each learning error
is taken net of its floor, ``max(E_n - F_n, 0)``, and the span's change is allowed what
the noise moves the estimate's extremes by.

The floor is the change a local mean makes when samples are added to it. Where ``n``
samples lie within the smoothing radius ``r`` of a place and ``k`` more arrive, the mean
of the noise moves by ``sigma sqrt(1/n - 1/(n + k))`` (standard deviation: the new
samples' own noise, weighted ``k / (n + k)``, against the old mean's), whose expected
absolute value is ``sqrt(2/pi)`` of it. ``F_n`` is that, averaged over the grid: places
that had no sample before count 0 (what changes there is the field, first seen).

A learning error is also small when an iteration flew little: E-CONDOR's ``delta`` may
drop all but one new level, whose pieces the fleet traces in a few tens of metres, and
the estimate then hardly moves because hardly anything new was sampled, not because the
map has converged. Three such *starved* iterations in a row give ``gamma`` about 1. So
the rule reads only iterations that flew at least ``FAIR_SHARE`` of what the run's
largest iteration so far flew (what an iteration of this mission and fleet can fly; a
median would call the starved iterations typical once they are the majority, and three
in a row are what fools ``gamma``), takes ``gamma`` over the last three of those, and
fires only right after one of them: convergence is a claim about new ground sampled, and
a starved iteration sampled too little to make it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from .geometry import FloatArray, Grid

__all__ = ["FAIR_SHARE", "SMOOTHING_RADIUS_M", "gamma", "gamma_converged", "noise_change",
           "noise_floor", "sampled_enough"]

SMOOTHING_RADIUS_M = 5.0
"""The radius over which the reconstruction averages noisy samples, about: half the
smoothing's tiles (:mod:`~econdor_gcs.core.smoothing`, 10 m squares); narrower over a
peak, wider over flat ground."""

FLOOR_SPACING_M = 2.0
"""The floor is averaged over cells this far apart (the radius is several of them)."""

FAIR_SHARE = 0.15
"""An iteration that flew less than this share of the largest iteration's flight is
*starved* (module docstring) and its learning error says nothing about convergence.
Between the two kinds E-CONDOR flies: one that traced a single level's few pieces flew
3-9 % of the run's largest iteration over ArduCopter SITL, while iterations that traced
several levels keep above a fifth of it even as the later ones grow to several times
the early ones (as the levels multiply)."""

SPAN_TOL = 0.01
"""The span may change by this share and still count as unchanged (the paper's 1 %)."""


def noise_change(before: FloatArray, after: FloatArray, noise_std: float) -> FloatArray:
    """Standard deviation of the change of a local mean of noisy samples from ``before``
    to ``after`` samples (elementwise; 0 where there were none before).

    >>> noise_change(np.array([0.0, 4.0, 4.0]), np.array([5.0, 4.0, 16.0]), 2.0).tolist()
    [0.0, 0.0, 0.8660254037844386]
    """
    b = np.asarray(before, dtype=float)
    a = np.maximum(np.asarray(after, dtype=float), b)
    with np.errstate(divide="ignore", invalid="ignore"):
        var = np.where(b > 0, 1.0 / np.maximum(b, 1e-300) - 1.0 / np.maximum(a, 1e-300), 0.0)
    return noise_std * np.sqrt(np.maximum(var, 0.0))


def _counts(tree: cKDTree | None, pts: FloatArray, radius_m: float) -> FloatArray:
    if tree is None:
        return np.zeros(len(pts))
    return np.asarray(tree.query_ball_point(pts, radius_m, return_length=True), dtype=float)


def noise_floor(x_m: FloatArray, y_m: FloatArray, n_before: int, grid: Grid,
                noise_std: float, radius_m: float = SMOOTHING_RADIUS_M) -> tuple[float, float]:
    """The learning error the noise alone makes when samples ``n_before:`` are added to
    samples ``:n_before`` (module docstring), and the largest standard deviation of that
    change anywhere (what the noise may move the estimate's extremes by).

    Parameters
    ----------
    x_m, y_m : ndarray
        Every sample so far, the new ones last.
    n_before : int
        How many of them the previous estimate had.
    grid : Grid
        The estimate's grid (the floor is averaged over its area).
    noise_std : float
        The samples' noise (0: no floor).

    Returns
    -------
    (float, float)
        The expected mean absolute change over the area, and the largest standard
        deviation of the change at one place.
    """
    if noise_std <= 0 or len(x_m) <= n_before:
        return 0.0, 0.0
    cells = Grid.with_spacing(grid.region, FLOOR_SPACING_M)
    xx, yy = cells.mesh
    pts = np.column_stack([xx.ravel(), yy.ravel()])
    xy = np.column_stack([x_m, y_m])
    before = _counts(cKDTree(xy[:n_before]) if n_before > 0 else None, pts, radius_m)
    after = _counts(cKDTree(xy), pts, radius_m)
    sd = noise_change(before, after, noise_std)
    return float(math.sqrt(2.0 / math.pi) * sd.mean()), float(sd.max(initial=0.0))


def gamma(errors: Sequence[float]) -> float:
    """``3 E_n / (E_n + E_{n-1} + E_{n-2})`` of the last three learning errors; 1 when
    all three are 0 (nothing changes: levelled off).

    >>> gamma([4.0, 2.0, 2.0]), gamma([0.0, 0.0, 0.0])
    (0.75, 1.0)
    """
    e2, e1, e0 = errors[-3], errors[-2], errors[-1]
    denom = e0 + e1 + e2
    return 3.0 * e0 / denom if denom > 0 else 1.0


def sampled_enough(flown_m: Sequence[float], share: float = FAIR_SHARE) -> list[bool]:
    """Which iterations flew at least ``share`` of what the largest of them flew (the
    others are starved: module docstring). Nothing flown anywhere: none did.

    >>> sampled_enough([835.0, 1540.0, 49.0, 66.0, 2226.0])
    [True, True, False, False, True]
    >>> sampled_enough([0.0, 0.0])
    [False, False]
    """
    if not len(flown_m):
        return []
    largest = max(flown_m)
    return [f > 0 and f >= share * largest for f in flown_m]


def gamma_converged(errors: Sequence[float], floors: Sequence[float], stop_lambda: float,
                    span_prev: float, span_now: float, span_noise: float = 0.0,
                    flown_m: Sequence[float] | None = None) -> bool:
    """The stop rule (module docstring) on the learning errors so far and their noise
    floors (0 for exact samples), and the spans of the last two estimates.

    ``flown_m`` is what each of those iterations flew: only the iterations that sampled
    enough count (:func:`sampled_enough`), and the last one must be among them. ``None``
    counts every iteration (all equally sampled).

    ``span_noise`` is what the noise may move the span by in the last iteration (the
    change of each extreme, both counted); a change within it and 1 % is no change.

    >>> gamma_converged([5.0, 1.0, 1.0, 1.0], [0, 0, 0, 0], 0.05, 90.0, 90.2)
    True
    >>> gamma_converged([5.0, 1.0, 1.0, 1.0], [0, 0, 0, 0], 0.05, 90.0, 92.0)
    False
    >>> # levelled off, but on its noise floor: what is left of it still falls
    >>> gamma_converged([5.0, 1.04, 1.02, 1.0], [0, 1.0, 1.0, 1.0], 0.05, 90.0, 90.2)
    False
    >>> gamma_converged([5.0, 1.04, 1.02, 1.0], [0, 0, 0, 0], 0.05, 90.0, 90.2)
    True
    >>> # starved: the last three flew a tenth of the largest iteration
    >>> gamma_converged([5.0, 0.04, 0.04, 0.04], [0, 0, 0, 0], 0.05, 90.0, 90.2,
    ...                 flown_m=[800.0, 60.0, 70.0, 60.0])
    False
    """
    if stop_lambda <= 0:
        return False
    if flown_m is not None:
        ok = sampled_enough(flown_m)
        if not ok or not ok[-1]:
            return False
        errors = [e for e, k in zip(errors, ok, strict=True) if k]
        floors = [f for f, k in zip(floors, ok, strict=True) if k]
    if len(errors) < 3:
        return False
    net = [max(e - f, 0.0) for e, f in zip(errors, floors, strict=True)]
    span_ok = span_now > 0 and abs(span_now - span_prev) <= SPAN_TOL * span_now + span_noise
    return abs(gamma(net) - 1.0) <= stop_lambda and span_ok
