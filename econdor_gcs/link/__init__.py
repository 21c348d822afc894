"""The ground station's MAVLink layer: codec, tlog, protocol state machines, UDP router."""

from .codec import Codec, Parser, mavlink
from .mission import (
    CommandSender,
    MissionClear,
    MissionDownloader,
    MissionItemSpec,
    MissionUploader,
    build_mission,
)
from .router import (
    MissionItemReached,
    Router,
    Sample,
    SamplePairer,
    StatusText,
    VehicleDiscovered,
    VehicleLink,
    VehicleLost,
    VehicleRecovered,
)
from .tlog import TlogWriter, read_tlog

__all__ = [
    "Codec",
    "CommandSender",
    "MissionClear",
    "MissionDownloader",
    "MissionItemReached",
    "MissionItemSpec",
    "MissionUploader",
    "Parser",
    "Router",
    "Sample",
    "SamplePairer",
    "StatusText",
    "TlogWriter",
    "VehicleDiscovered",
    "VehicleLink",
    "VehicleLost",
    "VehicleRecovered",
    "build_mission",
    "mavlink",
    "read_tlog",
]
