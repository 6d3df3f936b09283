"""Metrics (ATE, yaw/pitch/roll, MME, MPV, NND) and plots."""
