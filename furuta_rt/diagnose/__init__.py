"""`furuta-rt diagnose`: find the physics eq. 4 leaves out of a recording, model it, show the fit improve.

Public API: ``diagnose(recording, rig, options) -> Diagnosis`` (furuta_rt.diagnose.engine) for a continuous
recording; ``diagnose_recording`` (furuta_rt.diagnose.segments) for one that may have gaps (what the CLI runs); the
effect vocabulary is furuta_rt.model.effects.
"""

from furuta_rt.diagnose.engine import Diagnosis, Options, diagnose
from furuta_rt.diagnose.segments import SegmentedDiagnosis, diagnose_recording

__all__ = ["Diagnosis", "Options", "SegmentedDiagnosis", "diagnose", "diagnose_recording"]
