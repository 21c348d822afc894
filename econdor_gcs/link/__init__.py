"""The ground station's MAVLink layer.

``codec`` (pymavlink as a codec), ``transports`` (UDP, TCP, serial links), ``vehicles`` (the
sans-IO vehicle table: routes, companions, twins, strangers, liveness), ``pairing`` (samples
placed on each vehicle's position track), ``mission`` (protocol state machines),
``commands`` (the command vocabulary), ``router`` (the thin asyncio shell over them),
``autopilots`` (per-family procedures), ``tlog``, ``forward``, ``relay``.
"""

from econdor_gcs.link.transfer import (
    CommandSender,
    MissionClear,
    MissionDownloader,
    MissionItemSpec,
    MissionUploader,
    build_mission,
)

from .codec import Codec, Parser, mavlink
from .pairing import Sample, SamplePairer
from .router import Received, Router
from .tlog import TlogWriter, read_tlog
from .vehicles import (
    MissionItemReached,
    StatusText,
    VehicleDiscovered,
    VehicleLink,
    VehicleLost,
    VehicleRecovered,
    VehicleTable,
)

__all__ = [
    "Codec",
    "CommandSender",
    "MissionClear",
    "MissionDownloader",
    "MissionItemReached",
    "MissionItemSpec",
    "MissionUploader",
    "Parser",
    "Received",
    "Router",
    "Sample",
    "SamplePairer",
    "StatusText",
    "TlogWriter",
    "VehicleDiscovered",
    "VehicleLink",
    "VehicleLost",
    "VehicleRecovered",
    "VehicleTable",
    "build_mission",
    "mavlink",
    "read_tlog",
]
