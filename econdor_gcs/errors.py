"""The econdor exception tree.

::

    EcondorError                 base of everything the library raises on purpose
    ├── MissionError             a mission YAML that is malformed, incomplete or impossible
    ├── FieldError               a field model or raster that cannot be built or loaded
    ├── ReconstructionError      too few / degenerate samples to reconstruct a field
    ├── LinkError                MAVLink transport or protocol failure
    │   ├── VehicleTimeout       a vehicle stopped answering (or never appeared)
    │   └── ProtocolError        a peer answered with an error (e.g. MISSION_ACK != ACCEPTED)
    │       ├── MissionRejected  a mission (item) refused: ``result``, ``seq``, ``command``
    │       └── CommandRejected  a command refused: ``command``, ``result``
    ├── RunError                 a DFC run that cannot go on (carries the run directory)
    ├── ControlError             an operator's request that does not apply now (resume while running)
    └── WebError                 the web page cannot be served (address, run directory)

The CLI turns any ``EcondorError`` into one line on stderr and exit status 1.
"""

from __future__ import annotations


class EcondorError(Exception):
    """Base class of all errors econdor raises deliberately."""


class MissionError(EcondorError):
    """The mission file is malformed, has unknown/missing keys or impossible values."""


class FieldError(EcondorError):
    """A field model or raster cannot be built or loaded."""


class ReconstructionError(EcondorError):
    """The samples cannot support a reconstruction (too few, degenerate)."""


class LinkError(EcondorError):
    """MAVLink transport or protocol failure."""


class VehicleTimeout(LinkError):
    """A vehicle stopped answering, or never appeared."""


class ProtocolError(LinkError):
    """A peer answered a protocol step with an error."""


class MissionRejected(ProtocolError):
    """The vehicle refused a mission upload (MISSION_ACK with an error result).

    ``result`` is the MAV_MISSION_RESULT, ``seq`` the item it refused (None: the whole
    mission, e.g. no space), ``command`` that item's MAV_CMD (None when unknown).
    """

    def __init__(self, message: str, result: int, seq: int | None = None,
                 command: int | None = None) -> None:
        super().__init__(message)
        self.result = result
        self.seq = seq
        self.command = command


class CommandRejected(ProtocolError):
    """The vehicle answered a command with a result other than ACCEPTED / IN_PROGRESS.

    ``command`` is the MAV_CMD, ``result`` the MAV_RESULT.
    """

    def __init__(self, message: str, command: int, result: int) -> None:
        super().__init__(message)
        self.command = command
        self.result = result


class RunError(EcondorError):
    """A DFC run could not continue."""


class ControlError(EcondorError):
    """An operator's pause / resume / stop that does not apply in the run's current state."""


class WebError(EcondorError):
    """The web page cannot be served: a bad or busy address, or a run directory it cannot replay."""
