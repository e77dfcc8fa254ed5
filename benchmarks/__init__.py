"""Benchmarks of `furuta-rt diagnose` (imported by scripts/ and tests/ only; not part of the installed package):
concealed-effect suites (suite, suite_realistic), independent simulators (suite_independent, suite_independent_dc)
and the PySINDy comparison (sindy)."""
