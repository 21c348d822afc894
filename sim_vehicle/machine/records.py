"""The machine's records and its vocabulary: statuses, events, phases, program counters.

A task's state is one record of :data:`STATE`, made of one sub-record per part of the
machine, so that each phase's locals sit together and a phase function is handed only the
parts it works on:

``task`` (:data:`TASK`), ``params`` (:data:`PARAMS`)
    What the task is and the tracer's tuning (:class:`~sim_vehicle.tracer.TracerParams`).
``ctl`` (:data:`CONTROL`)
    The program counter, the command of this tick, the task's meters and outcome.
``fly`` (:data:`FLY`)
    The fly-to subroutine (:mod:`.fly`).
``cross`` (:data:`CROSSING`)
    The level-crossing detector shared by the search and the edge walk (:mod:`.crossing`):
    the previous sample, and where and with what gradient the level was found.
``search`` (:data:`SEARCH`)
    The search's probe legs, descent and spiral (:mod:`.search`).
``trace`` (:data:`TRACE`)
    The trace task's orchestration across its legs (:mod:`.trace`).
``leg`` (:data:`LEG`)
    One trace leg: the lateral controller and its end checks (:mod:`.leg`).
``walk`` (:data:`WALK`)
    The edge walk (:mod:`.walk`).
``track`` (:data:`TRACK`)
    The trace's own track, kept to tell when it comes back onto it (:mod:`.track`).

The body the machine flies is a separate record (:data:`BODY`) that outlives tasks.
"""

from __future__ import annotations

import numpy as np
from numba import njit

BODY = np.dtype([
    ("x_m", "f8"), ("y_m", "f8"), ("vx_mps", "f8"), ("vy_mps", "f8"), ("odometer_m", "f8"),
    ("last_heading_rad", "f8"), ("ticks", "i8"), ("t0_s", "f8"), ("dt_s", "f8"), ("n_sub", "i8"),
    ("max_speed_mps", "f8"), ("max_accel_mps2", "f8"), ("max_turn_rate_dps", "f8"),
    ("xmin", "f8"), ("xmax", "f8"), ("ymin", "f8"), ("ymax", "f8"),
    # the guard (see guard.guard): fence margin, breach attempts and breaches, hard brakes
    ("fence_margin_m", "f8"), ("fence_limited", "i8"), ("fence_attempts", "i8"),
    ("fence_last_tick", "i8"), ("fence_outside", "i8"), ("fence_breaches", "i8"),
    ("fence_event_tick", "i8"), ("fence_stuck", "i8"), ("guard_brakes", "i8"),
    # the onboard estimate of the readings' noise (see noise.noise_update): the last five
    # readings, the running mean squares of their fourth, fifth and first differences
    # (scaled), the count
    ("nh1", "f8"), ("nh2", "f8"), ("nh3", "f8"), ("nh4", "f8"), ("nh5", "f8"),
    ("noise_var", "f8"), ("noise_var5", "f8"), ("diff_var", "f8"), ("noise_n", "i8"),
])
"""The simulated vehicle's state (one record, shared by Python and compiled code)."""

_F = "f8"
_I = "i8"

TASK = np.dtype([
    ("kind", _I), ("level", _F), ("task_x_m", _F), ("task_y_m", _F), ("search_radius_m", _F),
    ("max_length_m", _F), ("wp_phase", _I), ("wp_tolerance_m", _F), ("wp_speed_mps", _F),
])
"""The task: a fly-to (``kind`` 1, the ``wp_*`` fields) or a trace (``kind`` 2)."""

PARAMS = np.dtype([
    ("speed_mps", _F), ("transit_speed_mps", _F), ("closure_radius_m", _F),
    ("closure_min_away_m", _F), ("search_speed_mps", _F), ("approach_speed_mps", _F),
    ("approach_gain_hz", _F), ("probe_leg_m", _F), ("spiral_spacing_m", _F),
    ("trace_bandwidth_rps", _F), ("trace_accel_mps2", _F), ("lateral_accel_fraction", _F),
    ("filter_alpha", _F), ("filter_beta", _F), ("gradient_window", _I), ("min_spread_m", _F),
    ("boundary_margin_m", _F), ("lost_offset_m", _F), ("lost_time_s", _F),
    ("reacquire_radius_m", _F), ("max_reacquire", _I), ("min_loop_radius_m", _F),
    ("budget_factor", _F), ("edge_skip_m", _F), ("recover_speed_mps", _F), ("recover_m", _F),
    ("edge_walk_m", _F), ("rejoin_min_m", _F), ("sensor_lag_s", _F),
    ("lag_unknown", _I),
])
"""The tracer's tuning, field for field :class:`~sim_vehicle.tracer.TracerParams`."""

CONTROL = np.dtype([
    ("pc", _I), ("status", _I), ("await_value", _I),
    # this tick's command (see command) and the odometer before it was flown
    ("cmd_vx", _F), ("cmd_vy", _F), ("cmd_phase", _I), ("odo_before", _F), ("area_guard", _I),
    # the whole task: where it began on the odometer, metres traced, the recent samples' ring
    ("odo0_m", _F), ("traced_m", _F), ("rec_start", _I), ("rec_len", _I),
    # this call of advance: samples produced and events written so far
    ("n_out", _I), ("n_events", _I),
])
"""The program counter, the command and the task's meters."""

FLY = np.dtype([
    ("x_m", _F), ("y_m", _F), ("phase", _I), ("tol_m", _F), ("speed_mps", _F),
    ("k", _I), ("k_max", _I), ("ok", _I), ("ret", _I),
])
"""A fly-to: target, sample phase, arrival radius, speed, ticks used and allowed, whether
it arrived, and where it returns."""

CROSSING = np.dtype([
    ("level", _F), ("ret", _I),
    ("has_prev", _I), ("prev_x", _F), ("prev_y", _F), ("prev_v", _F),
    ("found", _I), ("x_m", _F), ("y_m", _F), ("gx", _F), ("gy", _F),
    # the value filtered along the track when the readings are noisy (see crossing)
    ("vf", _F), ("prev_vf", _F), ("gain", _F),
])
"""The level looked for and where the detector returns when it finds it; the previous
sample; the crossing found and the gradient there."""

SEARCH = np.dtype([
    ("cx", _F), ("cy", _F), ("radius_m", _F), ("v_search", _F), ("v_min", _F),
    # probe legs
    ("probe_k", _I), ("arrival", _F), ("probe_ux", _F), ("probe_uy", _F), ("probe_x0", _F),
    ("probe_y0", _F), ("v_probe", _F), ("probe_j", _I), ("probe_n", _I),
    # descent
    ("best", _F), ("since_best", _I), ("path0", _F), ("max_path", _F),
    # spiral
    ("pitch", _F), ("phi0", _F), ("theta", _F), ("sp_k", _I), ("sp_max", _I),
])
"""A search: its disc, speeds and the locals of its probe legs, descent and spiral."""

TRACE = np.dtype([
    ("start_x", _F), ("start_y", _F), ("heading0", _F), ("back_edge_m", _F), ("side", _F),
    ("grad_mag", _F), ("grad_mag0", _F), ("away_max", _F), ("ticks_left", _I),
    ("reacquired", _I), ("lost_at_m", _F), ("slow_until_m", _F),
    ("has_good", _I), ("good_x", _F), ("good_y", _F), ("walks", _I),
])
"""A trace across its legs: where it began, the sense of the current leg, the gradient
magnitude carried from leg to leg, the tick budget, the losses and where the iso-line was
last held, the edge walks made."""

LEG = np.dtype([
    ("heading", _F), ("psi", _F), ("curvature_1pm", _F), ("speed_mps", _F),
    ("d_f", _F), ("dd_f", _F), ("lost_s", _F), ("has_prev_dist", _I), ("prev_dist", _F),
    ("n_fit", _I), ("turned", _F), ("th_start", _I), ("th_len", _I), ("turn_k", _I),
    ("turn_n", _I), ("ux", _F), ("uy", _F), ("heading_before", _F), ("status", _I),
    ("win_start", _I), ("win_len", _I), ("has_init", _I), ("d_init", _F), ("beta", _F),
    ("onto_prior", _I),
])
"""One trace leg: the commanded heading ``psi`` and the path curvature (the controller's
integral state), speed, the filtered lateral offset and its rate, the window of the
gradient fits and the turn history of the lost test; whether it ended on an earlier
trace's track."""

WALK = np.dtype([
    ("edge", _I), ("len_m", _F), ("odo0_m", _F), ("k", _I), ("k_max", _I),
    ("emax", _F), ("smax", _F), ("cross", _I), ("cx", _F), ("cy", _F), ("gx", _F),
    ("gy", _F), ("e", _F), ("de", _F),
])
"""An edge walk: the edge, its length, the highest value read and where, a crossing kept
near its start, the last offset from the level and its slope along the edge."""

TRACK = np.dtype([("len", _I), ("has", _I), ("x", _F), ("y", _F), ("m", _F)])
"""The trace's track: points kept, and the last one (position, metres traced there)."""

STATE = np.dtype([
    ("task", TASK), ("params", PARAMS), ("ctl", CONTROL), ("fly", FLY), ("cross", CROSSING),
    ("search", SEARCH), ("trace", TRACE), ("leg", LEG), ("walk", WALK), ("track", TRACK),
])
"""One task's state: a sub-record per part of the machine."""

RECENT_SAMPLES = 40
"""Recent samples a task keeps for its gradient fits (``x, y, value`` rows)."""

# task kinds
KIND_FLY_TO = 1
KIND_TRACE = 2

# statuses (see STATUS_NAMES)
REACHED, UNREACHABLE, CLOSED, BOUNDARY, LENGTH_LIMIT, NOT_FOUND, LOST, BUDGET = range(1, 9)
STATUS_NAMES = {REACHED: "reached", UNREACHABLE: "unreachable", CLOSED: "closed",
                BOUNDARY: "boundary", LENGTH_LIMIT: "length_limit", NOT_FOUND: "not_found",
                LOST: "lost", BUDGET: "budget"}

# events (see sim_vehicle.tracer.TracerEvent)
(EV_FOUND, EV_NOT_FOUND, EV_LOST_SEARCHING, EV_REACQUIRED, EV_BOUNDARY_OTHER, EV_BUDGET,
 EV_CLOSED, EV_BOUNDARY, EV_LENGTH_LIMIT, EV_LOST, EV_FENCE, EV_EDGE_WALK,
 EV_EDGE_FOUND, EV_LOST_OTHER, EV_PRIOR_OTHER) = range(1, 16)

# phases of the samples (econdor_gcs.core.tasks.Phase)
TRANSIT, SEARCHING, TRACING = 0, 1, 2

# Program counters: the tens say which part of the machine runs (``pc // 10``, see
# run.pre), the units where in it. A part that is called (fly-to, search, leg, walk)
# returns to the counter its caller left in its record (``fly.ret``, ``cross.ret``) or to
# the trace's fixed continuation (after a leg, after a walk).
PC_DONE = 0
PART_FLY, PART_SEARCH, PART_LEG, PART_WALK, PART_TRACE = 1, 2, 3, 4, 5

PC_FT = 10
PC_FT_END = 11

PC_SR_PROBE_START = 20
PC_SR_PROBE = 21
PC_SR_DESCENT_START = 22
PC_SR_DESCENT = 23
PC_SR_SPIRAL_START = 24
PC_SR_SPIRAL = 25

PC_LEG_START = 30
PC_LEG_TURN = 31
PC_LEG_MAIN_START = 32
PC_LEG_MAIN = 33

PC_WK_START = 40
PC_WK = 41

PC_TR_START = 50
PC_TR_SEARCH = 51
PC_TR_AFTER_SEARCH = 52
PC_TR_AFTER_LEG = 53
PC_TR_AFTER_REACQUIRE = 54
PC_TR_AFTER_RETURN = 55
PC_TR_END = 56
PC_TR_AFTER_BACKUP = 57
PC_TR_AFTER_WALK = 58
PC_TR_AFTER_EDGE_FOUND = 59


@njit(inline="always")
def emit(ctl, events: np.ndarray, code: int) -> None:
    """Write event ``code`` with the number of samples produced before it (a full buffer
    drops it)."""
    if ctl.n_events < events.shape[0]:
        events[ctl.n_events, 0] = code
        events[ctl.n_events, 1] = ctl.n_out
        ctl.n_events += 1


@njit(inline="always")
def command(ctl, vx: float, vy: float, phase: int) -> bool:
    """Issue this tick's velocity command (True: a phase function has commanded)."""
    ctl.cmd_vx = vx
    ctl.cmd_vy = vy
    ctl.cmd_phase = phase
    return True
