"""SampleLog is the one sample type: it slices like its columns (no field-by-field rebuilds)."""

from __future__ import annotations

import numpy as np
import pytest

from econdor_gcs.core.tasks import Phase, SampleLog


def _log(n: int = 6) -> SampleLog:
    k = np.arange(n, dtype=float)
    return SampleLog(k / 10, k, -k, 100 + k, (np.arange(n) % 4).astype(np.int8),
                     (np.arange(n) % 2).astype(np.int16))


def _rows(log: SampleLog) -> list[tuple]:
    return list(zip(log.t_s.tolist(), log.x_m.tolist(), log.y_m.tolist(), log.value.tolist(),
                    log.phase.tolist(), log.vehicle.tolist(), strict=True))


def test_a_mask_keeps_every_column_of_the_samples_it_selects() -> None:
    log = _log()
    kept = log[log.phase != Phase.SURVEY]
    assert isinstance(kept, SampleLog)
    assert _rows(kept) == [r for r in _rows(log) if r[4] != Phase.SURVEY]
    assert kept.phase.dtype == np.int8 and kept.vehicle.dtype == np.int16


def test_take_and_slices_select_rows_in_the_order_asked() -> None:
    log = _log()
    assert _rows(log.take([4, 0, 0])) == [_rows(log)[4], _rows(log)[0], _rows(log)[0]]
    assert _rows(log.take(np.array([5.0, 1.0]))) == [_rows(log)[5], _rows(log)[1]]
    assert _rows(log[1:3]) == _rows(log)[1:3]
    assert len(log.take([])) == 0
    with pytest.raises(TypeError, match="log\\[k:k \\+ 1\\]"):
        log[2]  # one sample is a log of one, not a row


def test_copy_owns_its_columns_and_a_log_has_columns_of_one_length() -> None:
    log = _log()
    c = log.copy()
    c.value[0] = -1.0
    assert log.value[0] == 100.0
    with pytest.raises(ValueError, match="differ in length"):
        SampleLog(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(2), np.zeros(3, np.int8),
                  np.zeros(3, np.int16))


def test_from_rows_with_and_without_the_vehicle_column() -> None:
    rows = [(0.0, 1.0, 2.0, 3.0, int(Phase.TRACE)), (0.5, 1.5, 2.5, 3.5, int(Phase.SEARCH))]
    log = SampleLog.from_rows(rows, vehicle=7)
    assert _rows(log) == [(*r, 7) for r in rows]
    assert _rows(SampleLog.from_rows([(*r, 2) for r in rows])) == [(*r, 2) for r in rows]
    assert len(SampleLog.from_rows([], vehicle=1)) == 0
