-- econdor_sensor.lua: a field sensor on an ArduPilot aircraft, for the econdor ground station.
--
-- Reads an analog sensor, scales it and sends it to the ground as NAMED_VALUE_FLOAT "FIELD"
-- at a set rate. ArduPilot stamps each message with its own clock (time_boot_ms) when it is
-- sent; the station places the sample where the aircraft was at that moment by interpolating
-- the aircraft's positions (GLOBAL_POSITION_INT, on the same clock).
--
-- Install: SCR_ENABLE 1, reboot, copy this file to APM/scripts/ on the SD card (SITL:
-- scripts/ in its working directory), reboot. It adds these parameters (table ECON_):
--   ECON_PIN      analog input pin of the sensor (board-specific; -1: off)      default 13
--   ECON_SCALE    value = (voltage - ECON_OFFSET_V) * ECON_SCALE                 default 1
--   ECON_OFFSET_V sensor voltage that reads 0                                     default 0
--   ECON_RATE_HZ  samples per second (the mission's vehicles.sample_rate_hz)       default 10
--   ECON_ARMED    1: send only while armed (a flight's samples), 0: always         default 1
-- Every second it also sends NAMED_VALUE_FLOAT "FIELD_N": how many FIELD it has sent so far.

local TABLE_KEY = 47
local TABLE_PREFIX = "ECON_"
assert(param:add_table(TABLE_KEY, TABLE_PREFIX, 5), "econdor_sensor: cannot add ECON_ parameters")
param:add_param(TABLE_KEY, 1, "PIN", 13)
param:add_param(TABLE_KEY, 2, "SCALE", 1)
param:add_param(TABLE_KEY, 3, "OFFSET_V", 0)
param:add_param(TABLE_KEY, 4, "RATE_HZ", 10)
param:add_param(TABLE_KEY, 5, "ARMED", 1)

local PIN = Parameter(TABLE_PREFIX .. "PIN")
local SCALE = Parameter(TABLE_PREFIX .. "SCALE")
local OFFSET_V = Parameter(TABLE_PREFIX .. "OFFSET_V")
local RATE_HZ = Parameter(TABLE_PREFIX .. "RATE_HZ")
local ARMED = Parameter(TABLE_PREFIX .. "ARMED")

local chan = analog:channel()
local pin = -2
local sent = 0
local last_count_ms = uint32_t(0)
local due_ms = millis()
local last_ms = uint32_t(0)

local function period_ms()
  local hz = RATE_HZ:get()
  if hz <= 0 then
    hz = 1
  end
  return math.max(1, math.floor(1000 / hz + 0.5))
end

local function update()
  if millis() == last_ms then
    return update, 1  -- one sample per millisecond at most: the stamp tells them apart
  end
  if PIN:get() ~= pin then
    pin = PIN:get()
    if pin >= 0 then
      chan:set_pin(pin)
    end
  end
  if pin >= 0 and (ARMED:get() == 0 or arming:is_armed()) then
    local volts = chan:voltage_average()
    gcs:send_named_float("FIELD", (volts - OFFSET_V:get()) * SCALE:get())
    sent = sent + 1
    last_ms = millis()
  end
  local now = millis()
  if now - last_count_ms >= uint32_t(1000) then
    last_count_ms = now
    gcs:send_named_float("FIELD_N", sent)
  end
  -- the next sample is due one period after this one was due, not after now: the
  -- scheduler's lateness does not add up (SITL at 30x runs the script ~40 % late)
  due_ms = due_ms + uint32_t(period_ms())
  if due_ms <= now then
    if now - due_ms > uint32_t(period_ms()) then
      due_ms = now  -- fell far behind (a busy autopilot): start again from now
    end
    return update, 1
  end
  return update, (due_ms - now):toint()
end

gcs:send_text(6, "econdor_sensor: FIELD at " .. tostring(RATE_HZ:get()) .. " Hz")
return update, period_ms()
