"""The econdor exception tree.

::

    EcondorError                 base of everything the library raises on purpose
    ├── MissionError             a mission YAML that is malformed, incomplete or impossible
    ├── FieldError               a field model or raster that cannot be built or loaded
    ├── ReconstructionError      too few / degenerate samples to reconstruct a field
    ├── LinkError                MAVLink transport or protocol failure
    │   ├── VehicleTimeout       a vehicle stopped answering (or never appeared)
    │   └── ProtocolError        a peer answered with an error (e.g. MISSION_ACK != ACCEPTED)
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


class RunError(EcondorError):
    """A DFC run could not continue."""


class ControlError(EcondorError):
    """An operator's pause / resume / stop that does not apply in the run's current state."""


class WebError(EcondorError):
    """The web page cannot be served: a bad or busy address, or a run directory it cannot replay."""
