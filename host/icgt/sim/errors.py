"""The simulator's errors: one for everything it refuses, one for a scenario file it cannot use."""

from __future__ import annotations

from icgt.errors import IcgtError

__all__ = ["ScenarioError", "SimError"]


class SimError(IcgtError):
    """A problem in the simulator (scenario, truth files, simulated devices)."""


class ScenarioError(SimError):
    """A scenario file that cannot be used; the message names the file and the key."""
