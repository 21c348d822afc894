"""The onboard tracer as a compiled state machine (numba, cached on disk).

This is the one implementation of the vehicle's flight logic: fly to a point, search
for a level near a start point, trace the iso-line (see :mod:`sim_vehicle.tracer` for
what the controller does and :class:`~sim_vehicle.tracer.TracerParams` for its tuning).
:func:`advance` runs a task for up to ``n`` sensor ticks and stops, keeping everything
it needs to go on in two numpy records:

``body`` (:data:`BODY`)
    The simulated vehicle: point-mass state, sim clock, limits and region. It belongs
    to a :class:`~sim_vehicle.body.SimBody` and outlives tasks.
``state`` (:data:`STATE`)
    One task: a sub-record per part of the machine (:mod:`.records`), plus four sample
    buffers passed beside it (the task's recent samples, the trace leg's window, the
    leg's turn history, the trace's track).

The parts, one module each:

=====================  ============================================================
:mod:`.fly`            fly to a point (the fly-to task; the trace's transits)
:mod:`.search`         probe legs, descent along the fitted gradient, spiral
:mod:`.crossing`       the level-crossing detector of the search and the edge walk
:mod:`.trace`          the trace task: which part runs after which
:mod:`.leg`            one trace leg: the lateral controller and its end tests
:mod:`.track`          the trace's track: closing on itself or an earlier trace
:mod:`.walk`           the edge walk at the area's boundary
:mod:`.fits`           gradient fits from the samples
:mod:`.guard`          every command limited to stop inside the fence and the area
:mod:`.vehicle`        the body's motion, the area's geometry
:mod:`.run`            the tick loop, dispatching to the parts
=====================  ============================================================

Each tick the parts' steps run until one issues a velocity command, then the kinematic
sub-steps, a sensor reading and what the commanding part does with the new sample. The
reading comes from the compiled Gaussian sum when the field is one; for any other field
``advance`` returns after moving with ``ctl.await_value`` set, the caller reads the field
at the body's position and calls again with the value. The Python generators of
:mod:`sim_vehicle.tracer` drive this one tick at a time (the MAVLink vehicle); the
in-process executor drives it thousands of ticks per call.

Events (contour found, lost, ...) are written to an ``events`` buffer as
``(code, samples produced before it)`` so an adapter can replay them between the
samples where they happened.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from econdor_gcs.core import fields as _fields

from .. import fence as _fence
from .. import kinematics as _kinematics
from .. import sensor as _sensor
from . import cache as _cache
from .fits import fit_cross_gradient, fit_gradient
from .records import (
    BODY,
    BOUNDARY,
    BUDGET,
    CLOSED,
    EV_BOUNDARY,
    EV_BOUNDARY_OTHER,
    EV_BUDGET,
    EV_CLOSED,
    EV_EDGE_FOUND,
    EV_EDGE_WALK,
    EV_FENCE,
    EV_FOUND,
    EV_LENGTH_LIMIT,
    EV_LOST,
    EV_LOST_OTHER,
    EV_LOST_SEARCHING,
    EV_NOT_FOUND,
    EV_PRIOR_OTHER,
    EV_REACQUIRED,
    KIND_FLY_TO,
    KIND_TRACE,
    LENGTH_LIMIT,
    LOST,
    NOT_FOUND,
    PC_DONE,
    REACHED,
    RECENT_SAMPLES,
    STATE,
    STATUS_NAMES,
    UNREACHABLE,
)
from .run import advance, start_task
from .trace import trace_tick_budget
from .vehicle import body_move

__all__ = [
    "BODY", "BOUNDARY", "BUDGET", "CLOSED", "EV_BOUNDARY", "EV_BOUNDARY_OTHER", "EV_BUDGET",
    "EV_CLOSED", "EV_EDGE_FOUND", "EV_EDGE_WALK", "EV_FENCE", "EV_FOUND", "EV_LENGTH_LIMIT",
    "EV_LOST", "EV_LOST_OTHER", "EV_LOST_SEARCHING", "EV_NOT_FOUND", "EV_PRIOR_OTHER",
    "EV_REACQUIRED", "KIND_FLY_TO",
    "KIND_TRACE", "LENGTH_LIMIT", "LOST", "NOT_FOUND", "PC_DONE", "REACHED", "RECENT_SAMPLES",
    "STATE", "STATUS_NAMES", "UNREACHABLE", "advance", "body_move", "cache_lock",
    "fit_cross_gradient", "fit_gradient", "start_task", "trace_tick_budget",
]


@contextlib.contextmanager
def cache_lock() -> Iterator[None]:
    """Hold an exclusive lock on the machine's compiled cache (processes starting together
    take turns: one compiles, the others load its result)."""
    with _cache.cache_lock(advance):
        yield


_cache.drop_stale_cache(advance, _cache.package_modules(__name__),
                        [_kinematics, _fields, _fence, _sensor])
