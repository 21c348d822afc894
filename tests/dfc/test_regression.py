"""Same behaviour as before the speed work: pinned in-process runs (issue 7).

The reference (``tests/data/regression.npz``) was recorded by
``tests/data/record_regression.py``, first from the code *before* the tracer was compiled
(pure-Python generators, numpy field evaluation), and again, from the compiled tracer,
when a trace begun at the area's edge stopped flying back to its start for the few
metres on the near side (``TracerParams.edge_skip_m``), and again when a lost contour came
to be taken up where the trace last held it (``TracerParams.recover_m``): four whole
in-process runs of the paper setting (``missions/paper.yaml``: authors' field, one
vehicle, diagonals then 8 iterations, econdor planner), paper seeds 0, 1, 2 and a plume
field (seed 3, the plume of ``bench/efficiency.py``). For each it holds every sample of
iterations 0 and 1 and the MAE after every iteration.

What is pinned, and why these tolerances
----------------------------------------
The tracer turns last-bit differences into different paths: its controller feeds on its
own samples, a crossing or a loop closure is a threshold decision, and a different path
gives different samples, hence a different estimate, other levels and other contour
pieces. We measured this on the reference code itself by scaling every sensed value by
``1 + e`` for ``e`` of one to four units in the last place (2.2e-16 .. 8.9e-16): the
samples of iteration 1 stayed within 1e-6 for their first 51-1122 samples (the 526 of
iteration 0 throughout) and then departed; the MAE
moved by at most 1.1 dB after iteration 1, by up to 4 dB after iteration 2 and by up to
38 dB in single runs later on (the method's outcome for one seed after 8 iterations is
that sensitive). The compiled tracer cannot be bit-identical (another summation order in
the Gaussian sum, libm's ``hypot`` for CPython's, a Gram-Schmidt fit for LAPACK's
least squares), so:

* **iteration 0** (the diagonals: no feedback, straight flight): every sample equal
  within ``1e-9`` (time, position, value, phase) and the MAE within 0.01 dB;
* **iteration 1**: its first ``ITERATION1_PREFIX`` = 50 samples (the transit to the first
  contour piece and the search for it) within ``1e-6``, and the MAE no worse than the
  reference + 1.5 dB;
* **iterations 2-8**: the MAE in dB, minus the reference, averaged over the four runs and
  the seven iterations (28 values), no worse than +5 dB. The same average over the
  perturbed reference runs was -1.9 .. +1.2 dB, while a tracer that loses contours or a
  reconstruction that is clearly less accurate moves it by tens of dB.

The MAE bounds are one-sided (no worse than the reference): a more accurate
reconstruction passes. Both the tracer and the reconstruction are exercised: iteration 0
runs the exact spline on 20 samples, later iterations the fast one on thousands.
Re-record only for an intended change of behaviour, and say why in the commit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from econdor_gcs.dfc.loop import RunResult
from tests.helpers.regression_cases import CASES, PINNED_ITERATIONS, run_case

ITERATION0_ABS = 1e-9
ITERATION1_PREFIX = 50
ITERATION1_ABS = 1e-6
MAE0_DB = 0.01
MAE1_DB = 1.5
LATER_MEAN_DB = 5.0

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def reference():
    from pathlib import Path

    with np.load(Path(__file__).resolve().parents[1] / "data" / "regression.npz") as data:
        return {k: data[k] for k in data.files}


@pytest.fixture(scope="module")
def runs() -> dict[str, RunResult]:
    return {name: run_case(name) for name in CASES}


def _samples(result: RunResult) -> np.ndarray:
    s = result.samples
    return np.column_stack([s.t_s, s.x_m, s.y_m, s.value, s.phase.astype(float)])


def _db(mae: np.ndarray) -> np.ndarray:
    return 20.0 * np.log10(mae)


@pytest.mark.parametrize("name", list(CASES))
def test_iteration0_samples_are_the_same(name, runs, reference):
    ref = reference[f"{name}/samples"]
    n0 = int(reference[f"{name}/counts"][0])
    got = _samples(runs[name])
    assert runs[name].records[0].samples == n0
    np.testing.assert_allclose(got[:n0], ref[:n0], rtol=0.0, atol=ITERATION0_ABS)


@pytest.mark.parametrize("name", list(CASES))
def test_iteration1_starts_with_the_same_samples(name, runs, reference):
    assert PINNED_ITERATIONS >= 2
    ref = reference[f"{name}/samples"]
    n0 = int(reference[f"{name}/counts"][0])
    got = _samples(runs[name])
    end = n0 + ITERATION1_PREFIX
    assert len(got) >= end and len(ref) >= end
    np.testing.assert_allclose(got[n0:end], ref[n0:end], rtol=0.0, atol=ITERATION1_ABS)


@pytest.mark.parametrize("name", list(CASES))
def test_mae_of_the_first_iterations(name, runs, reference):
    ref_db = _db(reference[f"{name}/mae"])
    got_db = _db(np.array([r.mae for r in runs[name].records]))
    assert len(got_db) == len(ref_db)  # same number of iterations
    assert abs(got_db[0] - ref_db[0]) <= MAE0_DB
    assert got_db[1] <= ref_db[1] + MAE1_DB, (got_db[1], ref_db[1])


def test_mae_of_later_iterations_on_average(runs, reference):
    diffs = []
    for name in CASES:
        ref_db = _db(reference[f"{name}/mae"])
        got_db = _db(np.array([r.mae for r in runs[name].records]))
        diffs.extend((got_db - ref_db)[2:])
    assert len(diffs) == 4 * 7
    mean = float(np.mean(diffs))
    assert math.isfinite(mean)
    assert mean <= LATER_MEAN_DB, f"mean MAE change over iterations 2-8: {mean:+.2f} dB"
