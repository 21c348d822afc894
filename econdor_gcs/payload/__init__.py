"""The payload side of a real aircraft: Lua scripts for ArduPilot.

* ``econdor_sensor.lua`` (shipped, :func:`sensor_script`): an analog sensor scaled by
  parameters, sent as ``NAMED_VALUE_FLOAT("FIELD")`` at a set rate (docs/payload.md).
* :func:`field_script`: for ArduPilot SITL, a script that senses a mission's synthetic field
  at the vehicle's position (``econdor export MISSION.yaml --format lua``), so that autopilot,
  payload and station are all real code and the run's MAE against the truth means something.

ArduPilot's Lua has 32-bit integers and single-precision floats: the position is taken as
integer degE7 relative to the origin (exact), then mapped to the station's local east/north
metres by a quadratic fitted to the station's own geodetic conversion
(:meth:`~econdor_gcs.core.geodesy.Origin.to_local_many`) over the area, so that a sample is
sensed where the station will place it (ArduPilot's own flat-earth distances differ from
WGS-84 by 0.1-0.2 %, 10-20 cm across 100 m, more than the field's resolution allows).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from econdor_gcs.config import Mission

from ..core.fields import FrontField, GaussianSumField
from ..errors import EcondorError

__all__ = ["SENSOR_SCRIPT", "enu_fit", "field_script", "sensor_script"]

SENSOR_SCRIPT = "econdor_sensor.lua"
FIT_MARGIN = 0.5
"""The position fit covers the area plus half its size on every side."""
FIT_TOLERANCE_M = 0.005
"""Largest error of the fitted east/north over the fitted box (checked when it is made)."""


def sensor_script() -> Path:
    """The shipped sensor script (package data)."""
    return Path(str(resources.files(__package__).joinpath(SENSOR_SCRIPT)))


def enu_fit(mission: Mission) -> tuple[int, int, list[float], list[float], float]:
    """``(lat0_e7, lon0_e7, east_coefs, north_coefs, max_error_m)``: east/north metres as
    ``c0 a + c1 b + c2 a^2 + c3 a b + c4 b^2`` of ``a`` = lat - lat0 and ``b`` = lon - lon0
    in degE7, least-squares over the area and its margin.

    >>> from econdor_gcs.config import parse_mission
    >>> m = parse_mission({"field": {"model": "paper"}})
    >>> lat0, lon0, ce, cn, err = enu_fit(m)
    >>> err < FIT_TOLERANCE_M
    True
    """
    o = mission.origin
    r = mission.region
    mx, my = FIT_MARGIN * r.width_m, FIT_MARGIN * r.height_m
    xs = np.linspace(r.xmin - mx, r.xmax + mx, 41)
    ys = np.linspace(r.ymin - my, r.ymax + my, 41)
    xx, yy = np.meshgrid(xs, ys)
    lat, lon, _ = o.to_global_many(xx.ravel(), yy.ravel(), 0.0)
    lat0_e7, lon0_e7 = round(o.lat_deg * 1e7), round(o.lon_deg * 1e7)
    a = np.round(lat * 1e7) - lat0_e7
    b = np.round(lon * 1e7) - lon0_e7
    # where the station places these integer positions
    e, n, _ = o.to_local_many((a + lat0_e7) / 1e7, (b + lon0_e7) / 1e7, 0.0)
    basis = np.column_stack([a, b, a * a, a * b, b * b])
    ce, *_ = np.linalg.lstsq(basis, e, rcond=None)
    cn, *_ = np.linalg.lstsq(basis, n, rcond=None)
    err = float(max(np.max(np.abs(basis @ ce - e)), np.max(np.abs(basis @ cn - n))))
    return lat0_e7, lon0_e7, [float(c) for c in ce], [float(c) for c in cn], err


def _floats(values: np.ndarray | list[float]) -> str:
    return "{" + ", ".join(f"{float(v):.9g}" for v in values) + "}"


def _field_lua(field: object) -> str:
    if isinstance(field, GaussianSumField):
        return f"""local CX = {_floats(field.cx_m)}
local CY = {_floats(field.cy_m)}
local INV2S2 = {_floats(field.inv2s2)}
local W = {_floats(field.weights * field.scale)}
local OFFSET = {field.offset:.9g}

local function field(x, y)
  local acc = OFFSET
  for i = 1, #W do
    local dx, dy = x - CX[i], y - CY[i]
    acc = acc + W[i] * math.exp(-(dx * dx + dy * dy) * INV2S2[i])
  end
  return acc
end
"""
    if isinstance(field, FrontField):
        isl = field.islands_m
        r = field.region
        return f"""local C = {_floats(field.centre_m)}
local N = {_floats(field.normal)}
local A, WL = {field.amplitude_m:.9g}, {field.wavelength_m:.9g}
local PHASE, WIDTH = {field.phase_rad:.9g}, {field.width_m:.9g}
local IX = {_floats(isl[:, 0])}
local IY = {_floats(isl[:, 1])}
local IR = {_floats(isl[:, 2])}
local BG, PEAK = {field.background:.9g}, {field.peak:.9g}
local SLOPE = {_floats(field.slope)}
local XMIN, YMIN, WX, WY = {r.xmin:.9g}, {r.ymin:.9g}, {r.width_m:.9g}, {r.height_m:.9g}

local function step(s)
  local e = math.exp(-2 * math.abs(s) / WIDTH)
  local t = (1 - e) / (1 + e)
  if s < 0 then t = -t end
  return 0.5 * (1 + t)
end

local function field(x, y)
  local dx, dy = x - C[1], y - C[2]
  local along = -dx * N[2] + dy * N[1]
  local s = dx * N[1] + dy * N[2] - A * math.sin(2 * math.pi * along / WL + PHASE)
  local h = step(s)
  for i = 1, #IR do
    local d = math.sqrt((x - IX[i]) ^ 2 + (y - IY[i]) ^ 2)
    h = math.max(h, step(IR[i] - d))
  end
  local plane = SLOPE[1] * (x - XMIN) / WX + SLOPE[2] * (y - YMIN) / WY
  return BG + (PEAK - BG) * (h + plane)
end
"""
    raise EcondorError(f"a {type(field).__name__} cannot be evaluated in a Lua script (Gaussian "
                       "sums and fronts can: field models paper, authors, plume, front)")


def field_script(mission: Mission, seed: int | None = None) -> str:
    """A Lua script for ArduPilot SITL that senses ``mission``'s field (seed ``seed``, default
    the mission's) at the vehicle's position and sends it as ``FIELD`` at the mission's
    sample rate while the vehicle flies (armed and likely flying: not the seconds on the
    ground after landing, which come after the station's last flight report), and
    ``FIELD_N``, its count, every second."""
    seed = mission.seed if seed is None else seed
    field = mission.build_field(seed)
    lat0, lon0, ce, cn, err = enu_fit(mission)
    if err > FIT_TOLERANCE_M:
        raise EcondorError(f"the area is too large for the script's position fit "
                           f"({err:.3f} m off)")
    period_ms = max(1, round(1000.0 / mission.vehicles.sample_rate_hz))
    return f"""-- econdor: the field of mission {mission.name!r} (model {mission.field_model}, seed {seed})
-- sensed at the vehicle's position, for ArduPilot SITL. Made by
-- `econdor export MISSION.yaml --format lua`; not for a real aircraft (it senses nothing).
-- Sends NAMED_VALUE_FLOAT "FIELD" every {period_ms} ms while it flies (the autopilot stamps
-- the time it is sent), and "FIELD_N" (how many it sent) every second.
-- Needs SCR_ENABLE 1 (and SCR_VM_I_COUNT >= {max(10000, 40 * _terms(field))}).

local LAT0, LON0 = {lat0}, {lon0}  -- the mission origin, degE7
local EAST = {_floats(ce)}
local NORTH = {_floats(cn)}
local PERIOD_MS = {period_ms}

{_field_lua(field)}
local function enu(loc)
  local a = (loc:lat() - LAT0) * 1.0
  local b = (loc:lng() - LON0) * 1.0
  local x = EAST[1] * a + EAST[2] * b + EAST[3] * a * a + EAST[4] * a * b + EAST[5] * b * b
  local y = NORTH[1] * a + NORTH[2] * b + NORTH[3] * a * a + NORTH[4] * a * b + NORTH[5] * b * b
  return x, y
end

local sent = 0
local last_count_ms = uint32_t(0)
local due_ms = millis()
local PERIOD = uint32_t(PERIOD_MS)
local last_ms = uint32_t(0)

local function update()
  if millis() == last_ms then
    return update, 1  -- one sample per millisecond at most: the stamp tells them apart
  end
  if arming:is_armed() and vehicle:get_likely_flying() then
    local loc = ahrs:get_location()
    if loc then
      local x, y = enu(loc)
      gcs:send_named_float("FIELD", field(x, y))
      sent = sent + 1
      last_ms = millis()
    end
  end
  local now = millis()
  if now - last_count_ms >= uint32_t(1000) then
    last_count_ms = now
    gcs:send_named_float("FIELD_N", sent)
  end
  -- due one period after the last was due (the scheduler's lateness does not add up)
  due_ms = due_ms + PERIOD
  if due_ms <= now then
    if now - due_ms > PERIOD then
      due_ms = now
    end
    return update, 1
  end
  return update, (due_ms - now):toint()
end

return update, PERIOD_MS
"""


def _terms(field: object) -> int:
    if isinstance(field, GaussianSumField):
        return len(field.weights)
    if isinstance(field, FrontField):
        return 10 + len(field.islands_m)
    return 0
