"""ICGT host software: the device protocol, the synchroniser and the tools around them."""

from icgt.errors import IcgtError
from icgt.ingest import read as read

__all__ = ["IcgtError", "__version__"]
__version__ = "0.1.0"
