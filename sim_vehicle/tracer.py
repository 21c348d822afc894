"""Onboard contour search and tracing for a simulated vehicle.

Everything here steers a :class:`~sim_vehicle.body.SimBody` with velocity commands
and learns about the field **only from the samples the body returns** (one per
tick, taken at the vehicle's own position). The generators yield every sample and
return a :class:`~econdor_gcs.core.tasks.TaskOutcome`.

Search
    After flying to the task's start point the vehicle takes a short probe leg
    across its arrival direction, fits a plane to its recent samples and flies down
    (or up) the estimated gradient toward the level, slowing as the predicted
    distance shrinks. If that fails (flat field, wrong way, left the search disc) it
    flies an Archimedean spiral around the start point out to ``search_radius_m``.
    The level is found as soon as two consecutive samples bracket it.

Trace
    A PID controller on the signed lateral offset ``d = (value - level) / |grad|``
    steers the heading of a constant-speed velocity command (higher values kept on
    the left, or on the right on the return leg). The integral term is the path
    curvature, which is also used to slow down in tight bends. ``|grad|`` is
    re-estimated from a plane fit over the recent trace samples whenever they are
    spread enough across the track. Loop closure, the region boundary (then the
    vehicle returns to the entry point and traces the other way), the length limit,
    loss of the contour (local re-search) and a hard tick budget end the trace.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Generator
from dataclasses import dataclass

import numpy as np

from econdor_gcs.core.geometry import Region
from econdor_gcs.core.tasks import Phase, TaskOutcome, TraceTask, Waypoint

from .body import Sample, SimBody
from .kinematics import wrap_angle_rad

EventCallback = Callable[[str], None]


@dataclass(frozen=True)
class TracerParams:
    """Tuning of the onboard search and trace controller.

    Parameters
    ----------
    speed_mps
        Cruise speed while tracing (clipped to the vehicle's speed limit).
    transit_speed_mps
        Speed of transit legs; None means the vehicle's ``max_speed_mps``.
    closure_radius_m
        The loop is closed when the vehicle passes within this distance of the point
        where tracing began, after having been at least ``closure_min_away_m`` away.
    closure_min_away_m
        How far from the trace start the vehicle must have been before closure counts.
    search_speed_mps
        Top speed while searching.
    approach_speed_mps
        Minimum search speed, reached when the predicted distance to the level is small.
    approach_gain_hz
        Search speed = this gain * predicted distance to the level (clipped).
    probe_leg_m
        Length of each probe leg flown at the start of the search.
    spiral_spacing_m
        Distance between successive turns of the fallback search spiral.
    trace_bandwidth_rps
        Closed-loop bandwidth of the lateral controller (triple pole at ``-p``); capped
        at ``0.3 * sample_rate_hz`` so the loop stays well inside the sample rate.
    trace_accel_mps2
        Tangential acceleration used to ramp the trace speed.
    lateral_accel_fraction
        Fraction of ``max_accel_mps2`` the trace controller may use for turning.
    filter_alpha, filter_beta
        Gains of the alpha-beta filter on the lateral offset and its rate.
    gradient_window
        Number of recent samples used for plane (gradient) fits.
    min_spread_m
        Minimum cross-track spread (std, m) of the window to trust a gradient fit.
    boundary_margin_m
        Stop tracing when the region boundary is this close along the heading.
    lost_offset_m
        Lateral offset (m) beyond which the contour is considered lost ...
    lost_time_s
        ... if it persists this long.
    reacquire_radius_m
        Radius of the local search used to reacquire a lost contour.
    max_reacquire
        Maximum number of reacquisition attempts per task.
    min_loop_radius_m
        A full turn of the heading within ``2 pi`` times this path length (without the
        loop closing) is taken as orbiting off the contour, i.e. the contour is lost.
    budget_factor
        Trace tick budget: this many region perimeters (plus ``max_length_m``) at
        half the cruise speed.
    """

    speed_mps: float = 8.0
    transit_speed_mps: float | None = None
    closure_radius_m: float = 3.0
    closure_min_away_m: float = 8.0
    search_speed_mps: float = 5.0
    approach_speed_mps: float = 1.5
    approach_gain_hz: float = 1.0
    probe_leg_m: float = 2.0
    spiral_spacing_m: float = 3.0
    trace_bandwidth_rps: float = 2.5
    trace_accel_mps2: float = 2.0
    lateral_accel_fraction: float = 0.8
    filter_alpha: float = 0.85
    filter_beta: float = 0.5
    gradient_window: int = 20
    min_spread_m: float = 0.3
    boundary_margin_m: float = 1.0
    lost_offset_m: float = 6.0
    lost_time_s: float = 3.0
    reacquire_radius_m: float = 8.0
    max_reacquire: int = 2
    min_loop_radius_m: float = 3.0
    budget_factor: float = 4.0


# ----------------------------------------------------------------------------- helpers


class _Meter:
    """Wraps a body: counts ticks, traced distance and keeps the recent samples."""

    def __init__(self, body: SimBody, window: int = 40) -> None:
        self.body = body
        self.odo0_m = body.odometer_m
        self.traced_m = 0.0
        self.ticks = 0
        self.recent: deque[Sample] = deque(maxlen=window)

    @property
    def flown_m(self) -> float:
        return self.body.odometer_m - self.odo0_m

    @property
    def last(self) -> Sample | None:
        return self.recent[-1] if self.recent else None

    def tick(self, vx_mps: float, vy_mps: float, phase: int) -> Sample:
        odo = self.body.odometer_m
        sample = self.body.tick(vx_mps, vy_mps, phase)
        if phase == Phase.TRACE:
            self.traced_m += self.body.odometer_m - odo
        self.ticks += 1
        self.recent.append(sample)
        return sample


def _emit(on_event: EventCallback | None, text: str) -> None:
    if on_event is not None:
        on_event(text)


def _fit_gradient(
    xs: np.ndarray, ys: np.ndarray, vs: np.ndarray, ridge: float = 1e-4
) -> tuple[float, float, float]:
    """Least-squares plane ``v = a + g . (p - mean p)`` through samples.

    Returns
    -------
    gx, gy, spread_m
        The gradient and the smallest standard deviation of the positions (how well
        the plane is determined across the track).
    """
    n = len(xs)
    if n < 3:
        return 0.0, 0.0, 0.0
    dx = xs - xs.mean()
    dy = ys - ys.mean()
    dv = vs - vs.mean()
    sxx = float(dx @ dx) / n
    syy = float(dy @ dy) / n
    sxy = float(dx @ dy) / n
    tr = sxx + syy
    det0 = sxx * syy - sxy * sxy
    lam_min = max(0.5 * tr - math.sqrt(max(0.25 * tr * tr - det0, 0.0)), 0.0)
    a = sxx + ridge
    d = syy + ridge
    det = a * d - sxy * sxy
    if det <= 0.0:
        return 0.0, 0.0, 0.0
    bx = float(dx @ dv) / n
    by = float(dy @ dv) / n
    gx = (d * bx - sxy * by) / det
    gy = (a * by - sxy * bx) / det
    return gx, gy, math.sqrt(lam_min)


def _fit_recent(samples: deque[Sample] | list[Sample], count: int) -> tuple[float, float, float]:
    tail = list(samples)[-count:]
    if len(tail) < 3:
        return 0.0, 0.0, 0.0
    arr = np.array([(s.x_m, s.y_m, s.value) for s in tail], dtype=float)
    return _fit_gradient(arr[:, 0], arr[:, 1], arr[:, 2])


def _fit_cross_gradient(samples: deque[Sample] | list[Sample]) -> tuple[float, float]:
    """Cross-track gradient magnitude from samples along a (curved) track.

    The samples are expressed in a local frame (``s`` along the chord of the window,
    ``n`` across it) and fitted with ``v = a + b s + c s^2 + g n``: the quadratic term
    absorbs the curvature of a contour that is being followed, so ``g`` is only
    determined by genuine excursions across the iso-line.

    Returns
    -------
    g_abs, spread_m
        ``|g|`` and the standard deviation of ``n`` left after removing a quadratic
        trend in ``s`` (how well ``g`` is determined).
    """
    n_pts = len(samples)
    if n_pts < 6:
        return 0.0, 0.0
    arr = np.array([(q.x_m, q.y_m, q.value) for q in samples], dtype=float)
    cx, cy = arr[:, 0] - arr[:, 0].mean(), arr[:, 1] - arr[:, 1].mean()
    chord_x, chord_y = arr[-1, 0] - arr[0, 0], arr[-1, 1] - arr[0, 1]
    chord = math.hypot(chord_x, chord_y)
    if chord < 1e-6:
        return 0.0, 0.0
    ux, uy = chord_x / chord, chord_y / chord
    along = cx * ux + cy * uy
    across = -cx * uy + cy * ux
    trend = np.column_stack([np.ones(n_pts), along, along * along])
    coef, *_ = np.linalg.lstsq(trend, across, rcond=None)
    resid = across - trend @ coef
    spread = float(np.sqrt(np.mean(resid * resid)))
    if spread <= 1e-9:
        return 0.0, spread
    design = np.column_stack([trend, across])
    coef_v, *_ = np.linalg.lstsq(design, arr[:, 2], rcond=None)
    return abs(float(coef_v[3])), spread


def _ray_to_edge_m(region: Region, x_m: float, y_m: float, ux: float, uy: float) -> float:
    """Distance from an inside point to the region boundary along unit vector ``(ux, uy)``."""
    if not region.contains(x_m, y_m):
        return 0.0
    dist = math.inf
    if ux > 1e-12:
        dist = min(dist, (region.xmax - x_m) / ux)
    elif ux < -1e-12:
        dist = min(dist, (region.xmin - x_m) / ux)
    if uy > 1e-12:
        dist = min(dist, (region.ymax - y_m) / uy)
    elif uy < -1e-12:
        dist = min(dist, (region.ymin - y_m) / uy)
    return dist


def _shrunk(region: Region, margin_m: float) -> Region:
    m = min(margin_m, 0.25 * region.width_m, 0.25 * region.height_m)
    return Region(region.xmin + m, region.xmax - m, region.ymin + m, region.ymax - m)


# ----------------------------------------------------------------------------- fly_to


def _fly_to(
    meter: _Meter,
    x_m: float,
    y_m: float,
    phase: int,
    tolerance_m: float,
    speed_mps: float,
) -> Generator[Sample, None, bool]:
    """Straight flight with a braking profile; returns True when within tolerance."""
    body = meter.body
    accel = body.limits.max_accel_mps2
    speed_mps = min(speed_mps, body.limits.max_speed_mps)
    dist0 = math.hypot(x_m - body.x_m, y_m - body.y_m)
    max_ticks = int(3.0 * (dist0 / max(speed_mps, 0.1) + 10.0) / body.dt_s) + 100
    for _ in range(max_ticks):
        ex, ey = x_m - body.x_m, y_m - body.y_m
        dist = math.hypot(ex, ey)
        if dist <= tolerance_m:
            return True
        # brake so as to stop at the target; small floor so we always get there
        v = min(speed_mps, math.sqrt(2.0 * 0.6 * accel * dist), max(2.0 * dist, 0.3))
        v = max(v, min(0.3, speed_mps))
        yield meter.tick(v * ex / dist, v * ey / dist, phase)
    return math.hypot(x_m - body.x_m, y_m - body.y_m) <= tolerance_m


def fly_to(
    body: SimBody,
    x_m: float,
    y_m: float,
    phase: int = Phase.TRANSIT,
    tolerance_m: float = 1.0,
    speed_mps: float | None = None,
) -> Generator[Sample, None, TaskOutcome]:
    """Fly straight to a point, sampling every tick.

    Parameters
    ----------
    body
        The simulated vehicle.
    x_m, y_m
        Target position.
    phase
        Phase tag of the samples.
    tolerance_m
        Arrival radius.
    speed_mps
        Cruise speed; None means the vehicle's maximum speed.

    Yields
    ------
    Sample
        One sample per tick.

    Returns
    -------
    TaskOutcome
        Status ``"reached"`` (or ``"unreachable"`` if a generous tick budget ran out).
    """
    meter = _Meter(body)
    speed = body.limits.max_speed_mps if speed_mps is None else float(speed_mps)
    ok = yield from _fly_to(meter, float(x_m), float(y_m), phase, tolerance_m, speed)
    return TaskOutcome(
        Waypoint(float(x_m), float(y_m)), "reached" if ok else "unreachable", meter.flown_m
    )


# ----------------------------------------------------------------------------- search


@dataclass
class _Found:
    x_m: float
    y_m: float
    gx: float
    gy: float


def _bracket(prev: Sample | None, cur: Sample, level: float) -> tuple[float, float] | None:
    """Interpolated crossing point if the level lies between two consecutive samples."""
    if prev is None:
        return None
    e0, e1 = prev.value - level, cur.value - level
    if e1 == 0.0:
        return cur.x_m, cur.y_m
    if e0 * e1 >= 0.0:
        return None
    t = e0 / (e0 - e1)
    return prev.x_m + t * (cur.x_m - prev.x_m), prev.y_m + t * (cur.y_m - prev.y_m)


def _found(
    meter: _Meter,
    params: TracerParams,
    prev: Sample | None,
    cur: Sample,
    cross: tuple[float, float],
) -> _Found:
    gx, gy, _ = _fit_recent(meter.recent, params.gradient_window)
    if prev is None:
        return _Found(cross[0], cross[1], gx, gy)
    # the bracketing pair gives the derivative along the last step: trust its sign
    sx, sy = cur.x_m - prev.x_m, cur.y_m - prev.y_m
    step = math.hypot(sx, sy)
    dv = cur.value - prev.value
    if step > 1e-9:
        ux, uy = sx / step, sy / step
        along = dv / step
        gfit_along = gx * ux + gy * uy
        if math.hypot(gx, gy) < 1e-12 or gfit_along * along <= 0.0:
            # the fit disagrees with the crossing itself: use the step direction
            gx, gy = along * ux, along * uy
    return _Found(cross[0], cross[1], gx, gy)


def _search(
    meter: _Meter,
    level: float,
    cx_m: float,
    cy_m: float,
    radius_m: float,
    params: TracerParams,
) -> Generator[Sample, None, _Found | None]:
    """Look for a crossing of ``level`` within ``radius_m`` of ``(cx_m, cy_m)``."""
    body = meter.body
    region = _shrunk(body.region, 0.5)
    accel = body.limits.max_accel_mps2
    v_search = min(params.search_speed_mps, body.limits.max_speed_mps)
    v_min = min(params.approach_speed_mps, v_search)
    phase = Phase.SEARCH
    radius_m = max(radius_m, 0.0)
    prev = meter.last

    def step(vx: float, vy: float) -> Sample:
        return meter.tick(vx, vy, phase)

    # ---- probe: a short leg across the arrival direction (two if still degenerate)
    arrival = 0.0
    if len(meter.recent) >= 2:
        q0, q1 = meter.recent[-2], meter.recent[-1]
        if math.hypot(q1.x_m - q0.x_m, q1.y_m - q0.y_m) > 1e-6:
            arrival = math.atan2(q1.y_m - q0.y_m, q1.x_m - q0.x_m)
    probe_dirs = [arrival + 0.5 * math.pi, arrival]
    for k, ang in enumerate(probe_dirs):
        _, _, spread = _fit_recent(meter.recent, params.gradient_window)
        if k > 0 and spread >= params.min_spread_m:
            break
        ux, uy = math.cos(ang), math.sin(ang)
        # turn toward the interior if the leg would leave the region
        if _ray_to_edge_m(region, body.x_m, body.y_m, ux, uy) < 2.0 * params.probe_leg_m:
            ux, uy = -ux, -uy
        x0, y0 = body.x_m, body.y_m
        v_probe = max(v_min, 0.5 * v_search)
        for _ in range(int(10.0 / body.dt_s)):
            if math.hypot(body.x_m - x0, body.y_m - y0) >= params.probe_leg_m:
                break
            cur = step(v_probe * ux, v_probe * uy)
            yield cur
            cross = _bracket(prev, cur, level)
            if cross is not None:
                return _found(meter, params, prev, cur, cross)
            prev = cur

    # ---- gradient descent toward the level
    best = math.inf
    since_best = 0
    path0 = meter.flown_m
    max_path = 3.0 * radius_m + 10.0
    while prev is not None:
        gx, gy, _ = _fit_recent(meter.recent, max(params.gradient_window, 30))
        gn = math.hypot(gx, gy)
        e = prev.value - level
        if gn < 1e-9:
            break
        sgn = -1.0 if e > 0 else 1.0
        ux, uy = sgn * gx / gn, sgn * gy / gn
        pred_m = abs(e) / gn
        v = min(max(params.approach_gain_hz * pred_m, v_min), v_search)
        cur = step(v * ux, v * uy)
        yield cur
        cross = _bracket(prev, cur, level)
        if cross is not None:
            return _found(meter, params, prev, cur, cross)
        prev = cur
        err = abs(cur.value - level)
        if err < best * 0.999:
            best, since_best = err, 0
        else:
            since_best += 1
        if (
            since_best > 20
            or math.hypot(cur.x_m - cx_m, cur.y_m - cy_m) > radius_m
            or meter.flown_m - path0 > max_path
            or not region.contains(cur.x_m, cur.y_m)
        ):
            break

    # ---- expanding Archimedean spiral around the start point
    pitch = params.spiral_spacing_m / (2.0 * math.pi)
    phi0 = math.atan2(body.y_m - cy_m, body.x_m - cx_m)
    theta = 2.0 * math.pi
    lookahead_m = 2.0
    max_ticks = int((math.pi * radius_m**2 / params.spiral_spacing_m + 4.0 * radius_m + 50.0)
                    / (0.5 * v_min) / body.dt_s) + 100

    def spiral_point(th: float) -> tuple[float, float]:
        r = pitch * th
        return region.clip(cx_m + r * math.cos(th + phi0), cy_m + r * math.sin(th + phi0))

    for _ in range(max_ticks):
        if pitch * theta > radius_m:
            return None
        px, py = spiral_point(theta)
        while math.hypot(px - body.x_m, py - body.y_m) < lookahead_m and pitch * theta <= radius_m:
            r = pitch * theta
            theta += 0.3 / math.hypot(r, pitch)
            px, py = spiral_point(theta)
        r = pitch * theta
        v = min(v_search, max(v_min, math.sqrt(0.5 * accel * r)))
        ex, ey = px - body.x_m, py - body.y_m
        dist = math.hypot(ex, ey)
        if dist < 1e-9:
            theta += 0.3 / math.hypot(r, pitch)
            continue
        cur = step(v * ex / dist, v * ey / dist)
        yield cur
        cross = _bracket(prev, cur, level)
        if cross is not None:
            return _found(meter, params, prev, cur, cross)
        prev = cur
    return None


# ----------------------------------------------------------------------------- trace


@dataclass
class _LegState:
    """Shared bookkeeping of one trace task across legs and reacquisitions."""

    start_x_m: float
    start_y_m: float
    away_max_m: float = 0.0
    grad_mag: float = 1.0
    grad_mag0: float = 1.0
    ticks_left: int = 0


def _trace_leg(
    meter: _Meter,
    task: TraceTask,
    params: TracerParams,
    state: _LegState,
    heading0_rad: float,
    side: float,
) -> Generator[Sample, None, str]:
    """Follow the level from the current position; ``side=+1`` keeps high values left.

    Returns one of ``"closed"``, ``"boundary"``, ``"length_limit"``, ``"lost"``,
    ``"budget"``.
    """
    body = meter.body
    region = body.region
    level = task.level
    dt = body.dt_s
    lim = body.limits
    cruise = min(params.speed_mps, lim.max_speed_mps)
    v_floor = min(params.approach_speed_mps, cruise)
    lat_accel = params.lateral_accel_fraction * lim.max_accel_mps2
    turn_max = math.radians(lim.max_turn_rate_dps)
    p = min(params.trace_bandwidth_rps, 0.3 / dt)
    alpha, beta = params.filter_alpha, params.filter_beta

    psi = heading0_rad
    kappa = 0.0
    speed = min(max(body.speed_mps, v_floor), cruise)
    last = meter.last
    e0 = (last.value - level) if last is not None else 0.0
    d_f = side * e0 / state.grad_mag
    dd_f = 0.0
    d_clip = 1.5 * params.lost_offset_m
    lost_s = 0.0
    prev_dist: float | None = None
    n_fit = 0
    turned_rad = 0.0
    turn_hist: deque[tuple[float, float]] = deque()
    orbit_m = 2.0 * math.pi * params.min_loop_radius_m
    window: deque[Sample] = deque(maxlen=params.gradient_window)

    # turn onto the initial heading slowly before the controller takes over
    for _ in range(int(3.0 / dt) + 1):
        if body.speed_mps < 0.5 or abs(wrap_angle_rad(body.heading_rad - psi)) < math.radians(15):
            break
        if state.ticks_left <= 0:
            return "budget"
        state.ticks_left -= 1
        cur = meter.tick(v_floor * math.cos(psi), v_floor * math.sin(psi), Phase.TRACE)
        yield cur
        window.append(cur)
        d_f = side * (cur.value - level) / state.grad_mag
    speed = min(max(body.speed_mps, v_floor), cruise)

    while True:
        if state.ticks_left <= 0:
            return "budget"
        state.ticks_left -= 1
        # --- lateral PID (integral state = path curvature)
        kp = 3.0 * p * p / speed
        kd = 3.0 * p / speed
        ki = p**3 / speed
        d_c = max(-d_clip, min(d_clip, d_f))
        w_max = min(turn_max, lat_accel / speed)
        omega = speed * kappa - kp * d_c - kd * dd_f
        k_need = max(abs(kappa), abs(omega) / speed)  # curvature the controller asks for
        omega = max(-w_max, min(w_max, omega))
        kappa -= ki / speed * d_c * dt
        k_max = w_max / speed
        kappa = max(-k_max, min(k_max, kappa))
        if body.speed_mps >= 0.5:
            psi = body.heading_rad
        psi += omega * dt
        ux, uy = math.cos(psi), math.sin(psi)
        # --- speed: cruise, slowed in bends and when the boundary is ahead
        v_target = cruise
        heading_before = body.heading_rad
        if k_need > 1e-9:
            v_target = min(v_target, math.sqrt(0.7 * lat_accel / k_need))
        edge = _ray_to_edge_m(region, body.x_m, body.y_m, ux, uy)
        v_target = min(v_target, math.sqrt(2.0 * 0.5 * lim.max_accel_mps2
                                           * max(edge - params.boundary_margin_m, 0.0)) + 0.5)
        v_target = max(v_target, v_floor if edge > 2.0 * params.boundary_margin_m else 0.5)
        if v_target > speed:
            speed = min(v_target, speed + params.trace_accel_mps2 * dt)
        else:
            speed = max(v_target, speed - 0.6 * lim.max_accel_mps2 * dt)
        cur = meter.tick(speed * ux, speed * uy, Phase.TRACE)
        yield cur
        # --- measurement update
        window.append(cur)
        n_fit += 1
        if n_fit % 4 == 0 and len(window) >= max(6, params.gradient_window // 2):
            gn, spread = _fit_cross_gradient(window)
            if spread >= params.min_spread_m and gn > 0.0:
                g_new = 0.8 * state.grad_mag + 0.2 * gn
                state.grad_mag = min(max(g_new, 0.25 * state.grad_mag0), 4.0 * state.grad_mag0)
        d_meas = side * (cur.value - level) / state.grad_mag
        d_pred = d_f + dd_f * dt
        resid = d_meas - d_pred
        d_f = d_pred + alpha * resid
        dd_f += beta / dt * resid
        # --- termination checks
        if task.max_length_m > 0.0 and meter.traced_m >= task.max_length_m:
            return "length_limit"
        dist = math.hypot(cur.x_m - state.start_x_m, cur.y_m - state.start_y_m)
        state.away_max_m = max(state.away_max_m, dist)
        if state.away_max_m >= max(params.closure_min_away_m, params.closure_radius_m) and (
            dist <= params.closure_radius_m and prev_dist is not None and dist > prev_dist
        ):
            return "closed"
        prev_dist = dist
        if not region.contains(cur.x_m, cur.y_m) or (
            _ray_to_edge_m(region, cur.x_m, cur.y_m, ux, uy) < params.boundary_margin_m
        ):
            return "boundary"
        turned_rad += wrap_angle_rad(body.heading_rad - heading_before)
        turn_hist.append((body.odometer_m, turned_rad))
        while body.odometer_m - turn_hist[0][0] > orbit_m:
            turn_hist.popleft()
        if abs(turned_rad - turn_hist[0][1]) >= 2.0 * math.pi:
            return "lost"
        lost_s = lost_s + dt if abs(d_meas) > params.lost_offset_m else 0.0
        if lost_s > params.lost_time_s:
            return "lost"


def _heading_from_gradient(gx: float, gy: float, side: float) -> float:
    """Heading along the iso-line with higher values on the left (side=+1) or right."""
    return math.atan2(-side * gx, side * gy)


def trace_contour(
    body: SimBody,
    task: TraceTask,
    params: TracerParams = TracerParams(),  # noqa: B008 - frozen, immutable default
    on_event: EventCallback | None = None,
) -> Generator[Sample, None, TaskOutcome]:
    """Fly to the task start, search for the level nearby and trace the iso-line.

    Parameters
    ----------
    body
        The simulated vehicle; its region bounds the trace.
    task
        Level, start point, search radius and maximum trace length (0 = unlimited).
    params
        Controller tuning.
    on_event
        Called with short human-readable strings at notable events.

    Yields
    ------
    Sample
        One sample per tick (phases TRANSIT, SEARCH, TRACE).

    Returns
    -------
    TaskOutcome
        Status ``"closed"``, ``"boundary"``, ``"length_limit"``, ``"not_found"`` or
        ``"lost"``; ``flown_m`` includes transit, ``traced_m`` only TRACE ticks.
    """
    meter = _Meter(body)
    region = body.region
    transit = params.transit_speed_mps or body.limits.max_speed_mps

    def outcome(status: str) -> TaskOutcome:
        return TaskOutcome(task, status, meter.flown_m, meter.traced_m)

    sx, sy = _shrunk(region, 0.5).clip(float(task.x_m), float(task.y_m))
    yield from _fly_to(meter, sx, sy, Phase.TRANSIT, 1.0, transit)
    found = yield from _search(meter, task.level, sx, sy, task.search_radius_m, params)
    if found is None:
        _emit(on_event, "contour not found")
        return outcome("not_found")
    _emit(on_event, "contour found")

    perimeter = 2.0 * (region.width_m + region.height_m)
    budget_m = params.budget_factor * perimeter + max(task.max_length_m, 0.0)
    cruise = min(params.speed_mps, body.limits.max_speed_mps)
    g0 = max(math.hypot(found.gx, found.gy), 1e-9)
    state = _LegState(found.x_m, found.y_m, grad_mag=g0, grad_mag0=g0,
                      ticks_left=int(budget_m / (0.5 * cruise) / body.dt_s) + 200)
    heading0 = _heading_from_gradient(found.gx, found.gy, 1.0)
    reacquired = 0
    side = 1.0
    heading = heading0
    status = "lost"
    while True:
        status = yield from _trace_leg(meter, task, params, state, heading, side)
        if status == "lost" and reacquired < params.max_reacquire:
            reacquired += 1
            _emit(on_event, "contour lost, searching")
            again = yield from _search(meter, task.level, body.x_m, body.y_m,
                                       params.reacquire_radius_m, params)
            if again is not None:
                _emit(on_event, "contour reacquired")
                heading = _heading_from_gradient(again.gx, again.gy, side)
                continue
            status = "lost"
        if status == "boundary" and side > 0:
            _emit(on_event, "boundary reached, tracing other direction")
            yield from _fly_to(meter, state.start_x_m, state.start_y_m, Phase.TRANSIT, 0.5,
                               transit)
            side = -1.0
            heading = heading0 + math.pi
            state.away_max_m = 0.0
            continue
        break
    if status == "budget":
        _emit(on_event, "trace budget exhausted")
        status = "lost"
    messages = {
        "closed": "loop closed",
        "boundary": "boundary reached",
        "length_limit": "length limit",
        "lost": "contour lost",
    }
    _emit(on_event, messages.get(status, status))
    return outcome(status)
