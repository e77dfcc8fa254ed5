"""Analyses of the closed loop beyond design: friction limit cycles (thesis section 4) and the
reproduction of the thesis' sections 4–7 on the simulator.

* ``describing_function``: G(s) from the arm friction torque to φ̇ for any u = L·x, its crossings of
  the negative real axis and the describing-function (DF) prediction for Coulomb friction.
* ``periodic_orbit``: the limit cycle as a periodic orbit of the nonlinear closed loop (shooting on a
  Poincaré section with the core simulator), and the long-simulation cross-check.
* ``reproduction`` / ``figures``: the runs, table and figures of ``scripts/reproduce_thesis``.
"""
