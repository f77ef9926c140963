"""PlatformIO test runner for `pio test -e native`: PlatformIO's own GoogleTest output parser.

platformio.ini sets ``test_framework = custom`` rather than ``googletest`` for one reason:
the googletest framework makes PlatformIO install GoogleTest from its registry, while the
native environment links the system's GoogleTest (Debian: libgtest-dev), as CMake and CI do.
The parsing of the test program's output is PlatformIO's, unchanged.
"""

from platformio.public import GoogletestTestRunner


class CustomTestRunner(GoogletestTestRunner):  # type: ignore[misc]
    """GoogleTest results as PlatformIO test cases; no registry library."""

    EXTRA_LIB_DEPS = None
