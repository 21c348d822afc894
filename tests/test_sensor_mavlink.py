"""The MAVLink vehicle's sensor: set by the mission file and by parameters, and what its
samples say over the link (GLOBAL_POSITION_INT + NAMED_VALUE_FLOAT "FIELD" pairs) follows
the model -- statistics over many samples, as in ``test_sensor.py`` for the body."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink
from vehicle_helpers import GcsLink, item_int, wait_for

from econdor_gcs.config import load_mission
from econdor_gcs.core.geometry import Region
from sim_vehicle.mavlink_vehicle import MavlinkVehicle
from sim_vehicle.sensor import SensorModel
from sim_vehicle.state import VehicleSettings

ROOT = Path(__file__).resolve().parents[1]
ORIGIN = load_mission(ROOT / "missions" / "demo.yaml").origin
REGION = Region(0.0, 2000.0, 0.0, 2000.0)


def ramp_x(x: float, y: float) -> float:
    """The field is the easting: a sample's value is where the sensor truly was."""
    return float(x)


def test_the_mission_file_sets_the_sensor():
    m = load_mission(ROOT / "missions" / "plume-noisy.yaml")
    v = MavlinkVehicle.from_mission(m, connect="udpin:127.0.0.1:0")
    v.start()  # and stop: the loop closes its sockets
    v.stop()
    st = v.state
    assert (st.params["NOISE_STD"], st.params["LAG_S"], st.params["POS_STD_M"],
            st.params["POS_TAU_S"]) == (1.0, 0.5, 1.0, 10.0)
    assert st.body.sensor_model == SensorModel(1.0, 0.5, 1.0, 10.0)


@pytest.fixture
def vehicle() -> Iterator[MavlinkVehicle]:
    v = MavlinkVehicle(ramp_x, REGION, ORIGIN, VehicleSettings(speedup=200.0, seed=7),
                       connect="udpin:127.0.0.1:0")
    v.start()
    try:
        yield v
    finally:
        v.stop()


@pytest.fixture
def gcs(vehicle: MavlinkVehicle) -> Iterator[GcsLink]:
    _, port = vehicle.local_address
    with GcsLink.to("127.0.0.1", port) as g:
        g.send(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3))
        g.recv_match("HEARTBEAT", timeout=5)
        yield g


def ll(x: float, y: float) -> tuple[float, float]:
    lat, lon, _ = ORIGIN.to_global(x, y)
    return lat, lon


def set_param(gcs: GcsLink, name: str, value: float) -> float:
    gcs.send(mavlink.MAVLink_param_set_message(1, 1, name.encode(), value, 9))
    return gcs.recv_match("PARAM_VALUE", lambda m: m.param_id == name).param_value


def test_sensor_parameters_are_checked_and_applied(vehicle, gcs):
    assert set_param(gcs, "LAG_S", -1.0) == 0.0  # rejected: the old value
    assert set_param(gcs, "POS_TAU_S", 0.0) == 10.0
    assert set_param(gcs, "POS_STD_M", 1.5) == 1.5
    assert set_param(gcs, "LAG_S", 0.7) == pytest.approx(0.7)
    # applied at the next idle tick: the body is rebuilt with the new sensor
    wait_for(lambda: vehicle.state.body.sensor_model.lag_s == pytest.approx(0.7), 5,
             "the new sensor")
    assert vehicle.state.body.sensor_model.position_std_m == 1.5


def fly_legs(gcs: GcsLink, legs: list[tuple[float, float]], first: bool) -> np.ndarray:
    """Fly waypoints; the samples received as ``(t_s, x_m, y_m, value, ve_mps, vn_mps)``
    rows."""
    items = [item_int(0, mavlink.MAV_CMD_NAV_TAKEOFF, alt=20, current=1)] if first else []
    items += [item_int(len(items) + k, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(*p), 20)
              for k, p in enumerate(legs)]
    last = len(items) - 1
    assert gcs.upload(1, items) == mavlink.MAV_MISSION_ACCEPTED
    if first:
        assert gcs.command_long(1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    gcs.keep = True
    gcs.received.clear()
    assert gcs.command_long(1, mavlink.MAV_CMD_MISSION_START).result == 0
    gcs.recv_match("MISSION_ITEM_REACHED", lambda m: m.seq == last, timeout=60)
    gcs.keep = False
    msgs = list(gcs.received)
    rows = []
    for prev, m in zip(msgs, msgs[1:], strict=False):
        if m.get_type() == "NAMED_VALUE_FLOAT" and m.name == "FIELD":
            assert prev.get_type() == "GLOBAL_POSITION_INT"
            assert prev.time_boot_ms == m.time_boot_ms
            x, y, _ = ORIGIN.to_local(prev.lat / 1e7, prev.lon / 1e7)
            rows.append((m.time_boot_ms / 1000.0, x, y, m.value, prev.vy / 100.0,
                         prev.vx / 100.0))
    return np.asarray(rows)


@pytest.mark.slow
def test_samples_over_mavlink_follow_the_sensor_model(vehicle, gcs):
    """One vehicle, three flights, the sensor set by parameters between them: the lag (the
    offset on a ramp), the noise (its std, white), the GNSS error (std, correlation)."""
    east = [(1900.0, 100.0)]
    rows = fly_legs(gcs, [(100.0, 100.0)], first=True)  # climb and settle at the start
    # the lag: on a constant-speed leg up the ramp the reading is speed * lag behind
    set_param(gcs, "LAG_S", 0.5)
    rows = fly_legs(gcs, east, first=False)
    t, x, value = rows[:, 0], rows[:, 1], rows[:, 3]
    speed = np.gradient(x, t)
    cruise = np.abs(speed - 8.0) < 0.05
    cruise[: np.argmax(cruise) + 50] = False
    assert cruise.sum() > 500
    assert np.median(x[cruise] - value[cruise]) == pytest.approx(8.0 * 0.5, abs=0.02)
    # the noise: white, with its std (the reading's lag off again)
    set_param(gcs, "LAG_S", 0.0)
    set_param(gcs, "NOISE_STD", 0.5)
    rows = fly_legs(gcs, [(100.0, 100.0), (1900.0, 100.0)], first=False)
    r = rows[:, 3] - rows[:, 1]
    n = len(r)
    assert n > 3000
    assert abs(r.std() / 0.5 - 1.0) < 4.0 / math.sqrt(2 * n)
    assert abs(np.corrcoef(r[1:], r[:-1])[0, 1]) < 4.0 / math.sqrt(n)
    # the GNSS error: the reported position minus the true one (the value, on the ramp)
    set_param(gcs, "NOISE_STD", 0.0)
    set_param(gcs, "POS_TAU_S", 1.0)
    set_param(gcs, "POS_STD_M", 1.0)
    rows = fly_legs(gcs, [(100.0, 100.0), (1900.0, 100.0)] * 2, first=False)
    e = rows[:, 1] - rows[:, 3]
    n_eff = len(e) * 0.1 / 2.0
    assert n_eff > 400
    assert abs(e.std() - 1.0) < 4.0 / math.sqrt(2 * n_eff)
    phi = float(np.dot(e[1:], e[:-1]) / np.dot(e[:-1], e[:-1]))
    assert -0.1 / math.log(phi) == pytest.approx(1.0, rel=0.2)
    # the velocity reported is the true one (GNSS Doppler): steady at cruise, while the
    # believed positions jump by the error's steps
    ve = rows[:, 4]
    cruise = np.abs(np.abs(ve) - 8.0) < 0.05
    assert cruise.sum() > 0.8 * len(ve)
    jumps = np.abs(np.diff(rows[:, 1]) / np.diff(rows[:, 0]) - ve[1:])[cruise[1:]]
    assert np.median(jumps) > 0.3
