"""The lab: the DFC loop flown by simulated vehicles in this process, and studies over seeds.

It sits above both the ground station (:mod:`econdor_gcs`, whose DFC loop it drives) and
the simulated vehicle (:mod:`sim_vehicle`, whose tracer it calls directly); neither of
those imports it.
"""
