"""Simulated MAVLink UAVs: kinematics, sensing, contour tracer and the vehicle side of MAVLink."""
