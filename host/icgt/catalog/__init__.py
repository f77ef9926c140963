"""The inspection catalogue: every flight of a programme as GeoParquet files, queried with DuckDB.

`icgt catalog add LOG --structure NAME [--images CARD] [--detections D...] [--catalog DIR]` reads a
recording with `icgt.read`, its flight summary with the report's reader (icgt.report.summary), its card
with the matcher (icgt.ingest.match), its footprints with the damage map's face and projector
(icgt.mapping) and, with detections, its defects with `icgt map`'s own pipeline, and writes five
GeoParquet 1.1 tables (schema.py) into the flight's partition ``DIR/structure=NAME/flight=ID/``
(writer.py). `icgt catalog query "SQL"` (query.py) runs DuckDB over views that span every partition.

Modules: `schema` (the declared tables, their units and the GeoParquet metadata), `collect` (the rows of
one flight from the project's readers), `store` (the catalogue folder: marker, lock, staging, atomic
publication, history), `compact` (a structure's flight folders merged into group files), `query`
(DuckDB with its spatial extension, Arrow out), `cli` (the commands).
"""

from icgt.errors import IcgtError


class CatalogError(IcgtError):
    """A catalogue operation refused: bad input (log, card, structure name, folder) or a catalogue of another
    version; the message says which and leaves the catalogue as it was."""


__all__ = ["CatalogError"]
