"""Durations of device operations other than motion: the planner's estimates of a campaign's lab
time, and what the simulated devices spend on their virtual clock, so a dry run takes the planned
time. They are planning estimates chosen for this lab, not device specifications.
"""

LASER_READING_S = 0.3
"""One distance reading of the laser distance meter, s."""

CAPTURE_SETUP_S = 0.5
"""Camera set-up before a frame stack (stream start, trigger arming), s."""

ROBOT_SETTLE_S = 1.0
"""Robot settling after a move, before a capture, s."""
