"""Record the regression reference of tests/dfc/test_regression.py from the current code.

    python tests/data/record_regression.py            # writes tests/data/regression.npz

For each pinned case (paper seeds 0-2, one plume seed; one vehicle, the econdor planner)
it stores the per-iteration MAE, sample counts and flight distances of the whole run, and
every sample of the first iterations (``PINNED_ITERATIONS``). Re-record only when a change
of behaviour is intended, and say so in the commit.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tests.helpers.regression_cases import CASES, PINNED_ITERATIONS, run_case  # noqa: E402


def main() -> None:
    out: dict[str, np.ndarray] = {}
    for name in CASES:
        t0 = time.perf_counter()
        result = run_case(name)
        counts = np.array([r.samples for r in result.records])
        s = result.samples
        n_pin = int(counts[PINNED_ITERATIONS - 1])
        out[f"{name}/samples"] = np.column_stack(
            [s.t_s, s.x_m, s.y_m, s.value, s.phase.astype(float)])[:n_pin]
        out[f"{name}/mae"] = np.array([r.mae for r in result.records])
        out[f"{name}/counts"] = counts
        out[f"{name}/flight_m"] = np.array([r.flight_distance_m for r in result.records])
        print(f"{name}: {len(result.records) - 1} iterations, {len(s)} samples, pinned {n_pin}, "
              f"final {result.records[-1].mae_db:.2f} dB, {time.perf_counter() - t0:.1f} s")
    np.savez_compressed(Path(__file__).with_name("regression.npz"), **out)


if __name__ == "__main__":
    main()
