"""The exact biharmonic spline (Sandwell 1987), and the estimators' shared entry.

References
----------
Sandwell, D. T. (1987). Biharmonic spline interpolation of GEOS-3 and SEASAT altimeter
data. *Geophysical Research Letters*, 14(2), 139-142. https://doi.org/10.1029/GL014i002p00139
"""

from __future__ import annotations

from typing import Self

from numpy.typing import ArrayLike

from econdor_gcs.core.greens import FloatArray, _evaluate, _solve_weights
from econdor_gcs.core.samples import _check_query, _check_samples, _merge_duplicates
from econdor_gcs.core.smoothing import Denoised, denoise
from econdor_gcs.errors import ReconstructionError

__all__ = ["BiharmonicSpline"]


class _Spline:
    """Shared public entry: validate once, smooth noisy samples, then the private fit that
    trusts its input."""

    noise_std: float | None = None

    def fit(self, x: ArrayLike, y: ArrayLike, v: ArrayLike) -> Self:
        """Fit the spline to samples ``v`` at ``(x, y)``.

        With ``noise_std=None`` the noise of the samples is estimated first
        (:func:`~econdor_gcs.core.noise.estimate_noise`: the samples in the order they
        were taken); noisy samples are smoothed (:func:`~econdor_gcs.core.smoothing.denoise`)
        and the spline interpolates the smoothed values, exact ones are interpolated as
        they are.

        Parameters
        ----------
        x, y : array_like
            Sample positions in metres (any shape, flattened), in the order taken.
        v : array_like
            Sample values, same size as ``x``.

        Returns
        -------
        self

        Raises
        ------
        ReconstructionError
            Fewer than 3 (distinct) samples, mismatched lengths or non-finite input.
        """
        xa, ya, va = _check_samples(x, y, v)
        d = denoise(xa, ya, va, self.noise_std)
        self._fit_checked(d.x, d.y, d.v, merged=d.smoothed)
        self._record_noise(d, xa.size)
        return self

    def _record_noise(self, d: Denoised, n_samples: int) -> None:
        self.noise_ = d.noise
        self.noise_std_ = d.noise.noise_std
        self.damping_m2_ = d.damping_m2
        self.n_samples_ = int(n_samples)

    def _fit_checked(self, x: FloatArray, y: FloatArray, v: FloatArray, *,
                     merged: bool) -> Self:
        raise NotImplementedError


class BiharmonicSpline(_Spline):
    """Exact biharmonic spline (Sandwell 1987; MATLAB ``griddata`` ``'v4'``).

    .. math::

        f(\\mathbf{x}) = \\sum_{i=1}^{N} w_i \\, g(|\\mathbf{x} - \\mathbf{x}_i|),
        \\quad g(r) = r^2 (\\ln r - 1),\\ g(0) = 0, \\quad G\\,w = v,

    solved densely with :func:`scipy.linalg.solve` (least squares if singular).
    Samples at identical positions are merged (mean value) first. Cost is
    ``O(N^2)`` memory and ``O(N^3)`` time -- use :class:`FastBiharmonicSpline`
    beyond a few thousand samples. Noisy samples are smoothed before (see
    :meth:`fit`).

    Parameters
    ----------
    noise_std : float or None
        Standard deviation of the samples' noise: ``None`` estimates it, ``0`` interpolates
        every sample exactly.

    Attributes
    ----------
    coords_ : tuple of ndarray
        ``(x, y)`` of the distinct sample positions actually used.
    force_ : ndarray
        The weights ``w``.
    n_samples_ : int
        Number of samples given to :meth:`fit` (before merging).
    noise_std_ : float
        The noise the fit assumed (estimated or given; ``0`` when none was found).
    noise_ : NoiseEstimate
        The noise estimate in full.
    damping_m2_ : ndarray
        The smoothing's damping per tile (empty when the samples were interpolated).

    References
    ----------
    Sandwell, D. T. (1987). Biharmonic spline interpolation of GEOS-3 and
    SEASAT altimeter data. *Geophys. Res. Lett.*, 14(2), 139-142.

    Examples
    --------
    >>> spl = BiharmonicSpline().fit([0, 10, 0, 10], [0, 0, 10, 10], [1, 2, 3, 4])
    >>> spl.predict([0, 10], [0, 10]).round(6)
    array([1., 4.])
    """

    def __init__(self, noise_std: float | None = None) -> None:
        self.noise_std = noise_std

    def _fit_checked(
        self, x: FloatArray, y: FloatArray, v: FloatArray, *, merged: bool
    ) -> BiharmonicSpline:
        self.n_samples_ = int(x.size)
        if not merged:
            x, y, v = _merge_duplicates(x, y, v)
        self.coords_ = (x, y)
        self.force_ = _solve_weights(x, y, v)
        return self

    def predict(self, x: ArrayLike, y: ArrayLike) -> FloatArray:
        """Evaluate the spline at ``(x, y)``; returns an array of the shape of ``x``."""
        if not hasattr(self, "force_"):
            raise ReconstructionError("BiharmonicSpline is not fitted; call fit() first")
        xq, yq, shape = _check_query(x, y)
        return _evaluate(self.coords_[0], self.coords_[1], self.force_, xq, yq).reshape(shape)
