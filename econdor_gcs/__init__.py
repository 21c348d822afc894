"""econdor: a MAVLink ground station that maps spatial fields by tracing iso-contours.

The data fusion center (DFC) picks contour levels with the E-CONDOR dual
stochastic-gradient method, sends UAVs to trace them, and reconstructs the field
from the samples they stream back.
"""

__version__ = "0.1.0"
