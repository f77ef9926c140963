"""`Doc`: what one field of a record type means, its unit and bounds.

Record types (the frame record, the ROS 2 messages, the recorder's topics) describe every field with it;
`icgt.recording.schemas` turns the descriptions into the JSON Schemas of the log's topics. It lives at the
bottom of the package so that a record type can be described without loading the recorder's writer.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Doc"]


@dataclass(frozen=True)
class Doc:
    """What one field means: put it in `Annotated[type, Doc(...)]` or `field(metadata={"doc": Doc(...)})`.

    `unit` is appended to the description in brackets (e.g. "distance to the surface [m]"), so it
    shows wherever Foxglove shows the schema; `minimum` and `maximum` become JSON Schema bounds.
    """

    description: str
    unit: str | None = None
    minimum: float | None = None
    maximum: float | None = None

    def text(self) -> str:
        return f"{self.description} [{self.unit}]" if self.unit else self.description
