"""The examples in the numerical modules' docstrings run (as scikit-image's do)."""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = ["econdor_gcs.core.gp", "econdor_gcs.core.uncertainty", "econdor_gcs.core.levels",
           "econdor_gcs.core.adaptive", "econdor_gcs.core.adaptive.base",
           "econdor_gcs.core.adaptive.threshold", "econdor_gcs.core.candidates",
           "econdor_gcs.core.tasks", "econdor_gcs.core.greens", "econdor_gcs.core.exact_spline",
           "econdor_gcs.core.fast_spline", "econdor_gcs.core.samples", "econdor_gcs.core.noise",
           "econdor_gcs.core.smoothing", "econdor_gcs.core.spline", "econdor_gcs.core.local_scale"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert result.failed == 0
