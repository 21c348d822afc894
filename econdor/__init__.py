"""The ``econdor`` command: the top layer that wires the ground station and the lab together.

Packages and the one direction their imports run (checked by import-linter, see
``pyproject.toml`` and ``tests/test_layers.py``)::

    econdor        the command line (this package)           -> econdor_lab, econdor_gcs
    econdor_lab    in-process fleets and studies             -> sim_vehicle, econdor_gcs
    sim_vehicle    the simulated MAVLink vehicle             -> econdor_gcs.core, .errors, .mission
    econdor_gcs    the ground station; econdor_gcs.core is   -> nothing above it
                   its pure numerics
"""

from econdor_gcs import __version__

__all__ = ["__version__"]
