"""`furuta-rt diagnose`: find the physics eq. 4 leaves out of a recording, model it, show the fit improve.

Public API: ``diagnose(recording, rig, options) -> Diagnosis`` (furuta_rt.diagnose.engine); the
effect vocabulary is furuta_rt.model.effects.
"""

from furuta_rt.diagnose.engine import Diagnosis, Options, diagnose

__all__ = ["Diagnosis", "Options", "diagnose"]
