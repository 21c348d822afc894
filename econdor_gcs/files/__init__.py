"""Files: the run directory, plans, autopilot mission files (QGC WPL, .plan) and figures."""
