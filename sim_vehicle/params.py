"""The parameter protocol of a simulated vehicle (PARAM_REQUEST_LIST, PARAM_REQUEST_READ,
PARAM_SET), I/O-free like the autopilot that owns it.

Every parameter is a REAL32 (:data:`~sim_vehicle.state.PARAM_NAMES`, in that order for
``param_index``). A PARAM_SET is answered by PARAM_VALUE with the value the vehicle now
holds: the new one, or the old one and a STATUSTEXT warning when the value is rejected (not
finite, negative, 0 where 0 means nothing, a speed above the vehicle's limit, an unknown
GCS failsafe action). SAMPLE_HZ and the sensor's (:data:`~sim_vehicle.state.SENSOR_PARAMS`)
apply from the next mission item, or at once when idle.
"""

from __future__ import annotations

import math
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from .state import GCS_FAILSAFE_ACTIONS, PARAM_NAMES, SENSOR_PARAMS, VehicleState
from .telemetry import Outbox

ZERO_OK = ("NOISE_STD", "LAG_S", "POS_STD_M", "GCS_FS_ACT")
"""Parameters that may be 0 (a perfect sensor); every other one must be > 0."""
MAX_SAMPLE_HZ = 1000.0


def param_id(msg: Any) -> str:
    """The parameter name of a PARAM_* message (bytes or str, NUL-padded)."""
    pid = msg.param_id
    if isinstance(pid, bytes):
        pid = pid.decode("ascii", "replace")
    return str(pid).rstrip("\x00")


class Parameters:
    """The vehicle's parameters, as ``state.params`` holds them; answers go to ``outbox``,
    and a request for a parameter it does not have counts in ``counters['rx_unhandled']``."""

    def __init__(self, state: VehicleState, outbox: Outbox, counters: dict[str, int]) -> None:
        self.state = state
        self.outbox = outbox
        self.counters = counters

    def value_msg(self, name: str) -> Any:
        return mavlink.MAVLink_param_value_message(
            name.encode(), float(self.state.params[name]), mavlink.MAV_PARAM_TYPE_REAL32,
            len(PARAM_NAMES), PARAM_NAMES.index(name))

    def on_request_list(self, msg: Any) -> None:
        for name in PARAM_NAMES:
            self.outbox.put(self.value_msg(name))

    def on_request_read(self, msg: Any) -> None:
        if 0 <= msg.param_index < len(PARAM_NAMES):
            self.outbox.put(self.value_msg(PARAM_NAMES[msg.param_index]))
            return
        name = param_id(msg)
        if name in self.state.params:
            self.outbox.put(self.value_msg(name))
        else:
            self.counters["rx_unhandled"] += 1

    def acceptable(self, name: str, value: float) -> bool:
        """Whether ``value`` may be set for the known parameter ``name``."""
        ok = math.isfinite(value) and (value >= 0 if name in ZERO_OK else value > 0)
        if name == "GCS_FS_ACT":
            ok = ok and value in GCS_FAILSAFE_ACTIONS.values()
        if name == "SPEED_MPS":
            ok = ok and value <= self.state.settings.max_speed_mps
        if name == "SAMPLE_HZ":
            ok = ok and value <= MAX_SAMPLE_HZ
        return ok

    def on_set(self, msg: Any) -> None:
        name = param_id(msg)
        if name not in self.state.params:
            self.outbox.statustext(f"unknown parameter {name}", mavlink.MAV_SEVERITY_WARNING)
            return
        value = float(msg.param_value)
        if self.acceptable(name, value):
            self.set(name, value)
        else:
            self.outbox.statustext(f"{name}: rejected {value:g}", mavlink.MAV_SEVERITY_WARNING)
        self.outbox.put(self.value_msg(name))

    def set(self, name: str, value: float) -> None:
        """Set a parameter (SPEEDUP: the I/O loop re-anchors its clock when it sees it
        change)."""
        st = self.state
        st.params[name] = value
        if name == "SPEED_MPS":
            st.speed_mps = value
        elif name == "SAMPLE_HZ" or name in SENSOR_PARAMS:
            st.body_dirty = True  # applied at the next item boundary / idle tick
        elif name == "SEARCH_RAD_M":
            st.settings.search_radius_m = value
        elif name == "ALT_M":
            st.settings.altitude_m = value
