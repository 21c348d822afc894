"""The applications: ``econdor run``, ``upload``, ``export``, the fleet of simulated
vehicles, the terminal and web views."""
