"""The dual stochastic-gradient updates of E-CONDOR (paper eqs. 6 and 7).

Level increment (eq. 6)::

    kappa_n = kappa_{n-1} + ceil(1 + 2 |E_{n-2} - E_{n-1}| / |E_{n-2} + E_{n-1}|)

Redundancy radius (eq. 7)::

    delta_n = delta_{n-1} * |1 - 2 (E_{n-2} - E_{n-1}) / (E_{n-2} + E_{n-1})|

``E`` is the learning error (eq. 3). Both divide by ``E_{n-2} + E_{n-1}``, which is zero
when two consecutive iterations changed nothing (e.g. nothing new was traced). We treat
the normalised gradient as **0** then — no evidence of change — so ``kappa`` grows by one
and ``delta`` is kept. The same applies while fewer than two learning errors exist.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from .geometry import FloatArray


def normalised_gradient(e_prev2: float | None, e_prev1: float | None) -> float:
    """``2 (E_{n-2} - E_{n-1}) / (E_{n-2} + E_{n-1})``, 0 when undefined (see module doc)."""
    if e_prev2 is None or e_prev1 is None:
        return 0.0
    s = e_prev2 + e_prev1
    if not math.isfinite(s) or s == 0.0:
        return 0.0
    return 2.0 * (e_prev2 - e_prev1) / s


def update_kappa(kappa_prev: int, e_prev2: float | None, e_prev1: float | None) -> int:
    """Eq. (6).

    >>> update_kappa(1, 4.0, 2.0)   # 1 + ceil(1 + 2*2/6) = 1 + 2
    3
    """
    g = abs(normalised_gradient(e_prev2, e_prev1))
    return int(kappa_prev + math.ceil(1.0 + g - 1e-12))


def update_delta(delta_prev: float, e_prev2: float | None, e_prev1: float | None) -> float:
    """Eq. (7).

    >>> round(update_delta(0.9, 4.0, 2.0), 6)   # 0.9 * |1 - 2*2/6|
    0.3
    """
    return float(delta_prev * abs(1.0 - normalised_gradient(e_prev2, e_prev1)))


def initial_delta(levels: ArrayLike) -> float:
    """The authors' initial delta: the smallest gap between the first levels."""
    lv = np.sort(np.asarray(levels, dtype=float))
    if lv.size < 2:
        return 0.0
    return float(np.min(np.diff(lv)))


def drop_redundant(
    levels: ArrayLike, traced: Sequence[float], delta: float
) -> tuple[FloatArray, FloatArray]:
    """Split ``levels`` into (kept, dropped): a level within ``delta`` of any traced level
    is redundant (the second SG process).

    >>> drop_redundant([1.0, 2.0, 3.0], [2.1], 0.2)
    (array([1., 3.]), array([2.]))
    """
    lv = np.asarray(levels, dtype=float)
    if len(traced) == 0 or delta <= 0:
        return lv.copy(), np.zeros(0)
    tr = np.asarray(traced, dtype=float)
    near = np.min(np.abs(lv[:, None] - tr[None, :]), axis=1) < delta
    return lv[~near], lv[near]
