"""Recordings in and out: CSV (t, theta, theta_dot, phi, u) and MCAP logs."""
