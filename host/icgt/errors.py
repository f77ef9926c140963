"""The exceptions of the icgt package: everything raised on purpose derives from IcgtError."""


class IcgtError(Exception):
    """Root of every error the icgt package raises on purpose."""


class ProtocolError(IcgtError):
    """A problem with the device wire protocol."""


class EncodeError(ProtocolError):
    """A message cannot be put on the wire (a value out of range, a string too long)."""


class VersionMismatchError(ProtocolError):
    """The device speaks a protocol version this host does not."""

    def __init__(self, device_version: int, host_version: int) -> None:
        super().__init__(
            f"device speaks protocol version {device_version}, this host speaks version {host_version}; "
            "flash matching firmware or install the matching icgt release"
        )
        self.device_version = device_version
        self.host_version = host_version
