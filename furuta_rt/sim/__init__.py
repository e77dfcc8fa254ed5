"""Simulation of the rig (fixed step, physics substeps) and closed-loop runs."""
