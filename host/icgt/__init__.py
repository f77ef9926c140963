"""ICGT host software: the device protocol, the synchroniser and the tools around them."""

import sys

if sys.version_info < (3, 11):  # noqa: UP036 - this check is what tells an older Python's user why
    raise ImportError(
        f"icgt needs Python 3.11 or newer; this is Python {sys.version.split()[0]}. On Ubuntu 22.04 "
        "(Python 3.10) install python3.11 and python3.11-venv and run: make PYTHON=python3.11"
    )

from icgt.errors import IcgtError
from icgt.ingest import read as read
from icgt.version import __version__

__all__ = ["IcgtError", "__version__"]
