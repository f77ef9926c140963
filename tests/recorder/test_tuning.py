"""The interpreter settings of a recording: applied at start, restored at stop."""

from __future__ import annotations

import gc
import sys

from icgt.recorder.tuning import GC_THRESHOLDS, SWITCH_INTERVAL_S, InterpreterTuning


def test_apply_then_restore() -> None:
    before = (sys.getswitchinterval(), gc.get_threshold(), gc.get_freeze_count())
    tuning = InterpreterTuning()
    tuning.apply()
    try:
        assert sys.getswitchinterval() == min(before[0], SWITCH_INTERVAL_S)
        assert gc.get_threshold() == GC_THRESHOLDS
        assert gc.get_freeze_count() > before[2]  # start-up's objects are no longer scanned
        tuning.apply()  # idempotent: a second apply does not overwrite what restore gives back
    finally:
        tuning.restore()
    assert (sys.getswitchinterval(), gc.get_threshold(), gc.get_freeze_count()) == (before[0], before[1], 0)
    tuning.restore()  # idempotent
    assert gc.get_threshold() == before[1]
