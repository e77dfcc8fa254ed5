"""Physical models of the rig: plant (eq. 4), friction laws (eq. 1–3), actuator and sensor path.

Each model is defined once here and used by the simulator, the controller's compensation,
hil_mock and the diagnosis.
"""
