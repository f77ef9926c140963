"""One running ExifTool process (PyExifTool, ``-stay_open``) for the geotag writer and its read-back.

Why ExifTool (Phil Harvey's ``exiftool``, Debian ``libimage-exiftool-perl``, driven through
``pyexiftool``) and not exiv2's Python binding or pyexiv2: the geotagged copies must keep every
byte of metadata the camera wrote apart from the tags we set. ExifTool edits a file in place of
its own model of each maker note: it copies maker notes it does not change as they are, moves them
with their offsets fixed (or keeps them where they were), keeps IFD1 thumbnails, preview images
and MPF (multi-picture) trailers, keeps every tag's type, and re-serialises XMP by namespace URI
whatever prefixes the camera used. exiv2 rebuilds the whole TIFF structure and re-encodes the
maker notes it knows from its parsed model, which is where maker-note damage comes from. ExifTool
also writes XMP sidecars for every RAW format (ARW, DNG, NEF, CR2, CR3) with the same commands, and
it is the tool the photogrammetry community checks files with (``exiftool -validate``). The cost is
a Perl process: one stays open per CPU core for the whole export (pyexiftool's ``-stay_open``
protocol), so each image costs one write, not a process start; the reads before and after are
done in-process (`icgt.export.tag_reader`), ExifTool reading only what that cannot parse.

The two XMP namespaces ExifTool 12.57 (Debian 12) does not define are declared in a generated
ExifTool config file (`config_text`): Pix4D's camera namespace (``Camera:``, read by ODM,
OpenSfM, Pix4D and Metashape) and ours (``icgt:``).
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

from icgt.export import ExportError

EXIFTOOL_MIN_VERSION = (12, 15)
"""PyExifTool 0.5 needs ExifTool 12.15 or later; Debian 12 ships 12.57 (the version tested)."""

NS_CAMERA = "http://pix4d.com/camera/1.0/"
NS_ICGT = "urn:icgt:ns:geotag:1.0/"
CAMERA_TAGS = ("Yaw", "Pitch", "Roll", "GPSXYAccuracy", "GPSZAccuracy")

# Written as attributes of one rdf:Description: OpenSfM reads only the first rdf:Description and
# only attributes ("@Camera:Yaw"); ODM reads attributes and elements of every Description.
XMP_LAYOUT = ["-api", "compact=shorthand,onedesc"]


def config_text(icgt_tags: Iterable[str]) -> str:
    """ExifTool user-defined tables for the Camera (Pix4D) and icgt XMP namespaces (Perl, ExifTool's config format)."""
    cam = " ".join(f"{t} => {{ Writable => 'real' }}," for t in CAMERA_TAGS)
    ours = " ".join(f"{t} => {{}}," for t in sorted(set(icgt_tags)))
    return (
        "%Image::ExifTool::UserDefined = (\n"
        "  'Image::ExifTool::XMP::Main' => {\n"
        "    Camera => { SubDirectory => { TagTable => 'Image::ExifTool::UserDefined::Camera' } },\n"
        "    icgt => { SubDirectory => { TagTable => 'Image::ExifTool::UserDefined::icgt' } },\n"
        "  },\n"
        ");\n"
        "%Image::ExifTool::UserDefined::Camera = (\n"
        "  GROUPS => { 0 => 'XMP', 1 => 'XMP-Camera', 2 => 'Camera' },\n"
        f"  NAMESPACE => {{ 'Camera' => '{NS_CAMERA}' }},\n"
        f"  {cam}\n"
        ");\n"
        "%Image::ExifTool::UserDefined::icgt = (\n"
        "  GROUPS => { 0 => 'XMP', 1 => 'XMP-icgt', 2 => 'Location' },\n"
        f"  NAMESPACE => {{ 'icgt' => '{NS_ICGT}' }},\n"
        "  WRITABLE => 'string',\n"
        f"  {ours}\n"
        ");\n"
        "1;\n"
    )


def exiftool_path() -> str:
    path = shutil.which("exiftool")
    if path is None:
        raise ExportError(
            "exiftool not found: the geotagged copies are written with ExifTool "
            "(Debian/Ubuntu: apt-get install libimage-exiftool-perl; other systems: exiftool.org)"
        )
    return path


class ExifToolSession:
    """A context manager around one ``exiftool -stay_open`` process with our config loaded."""

    def __init__(self, icgt_tags: Iterable[str]) -> None:
        import exiftool  # pyexiftool

        exe = exiftool_path()
        self._exe = exe
        self.version: tuple[int, int] = (0, 0)
        self._dir = tempfile.TemporaryDirectory(prefix="icgt-exiftool-")
        cfg = Path(self._dir.name) / "icgt.config"
        cfg.write_text(config_text(icgt_tags), encoding="utf-8")
        self._et = exiftool.ExifTool(executable=exe, common_args=["-charset", "filename=utf8"], config_file=cfg)

    def __enter__(self) -> ExifToolSession:
        try:
            self._et.run()
            major, minor = str(self._et.version).split(".")[:2]
            self.version = (int(major), int(minor))
        except Exception as exc:  # pyexiftool raises its own kinds when the process does not start
            self._dir.cleanup()
            raise ExportError(f"cannot start {self._exe}: {exc}") from exc
        if self.version < EXIFTOOL_MIN_VERSION:
            self.__exit__(None, None, None)
            want = ".".join(map(str, EXIFTOOL_MIN_VERSION))
            raise ExportError(
                f"{self._exe} is ExifTool {self.version[0]}.{self.version[1]:02d}: {want} or later needed"
            )
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        try:
            self._et.terminate()
        finally:
            self._dir.cleanup()

    def run(self, args: Sequence[str]) -> tuple[int, str, str]:
        """(exit status, stdout, stderr) of one exiftool command."""
        try:
            out = self._et.execute(*[str(a) for a in args])
        except Exception as exc:  # a dead process, a broken pipe
            raise ExportError(f"exiftool failed: {exc}") from exc
        status = self._et.last_status
        return (int(status) if status is not None else 0), str(out or ""), str(self._et.last_stderr or "")

    def read_json(self, files: Sequence[Path], tags: Sequence[str]) -> dict[Path, dict[str, Any]]:
        """Numeric values (-n) of `tags` of many files, by family-1 group ("XMP-Camera:Yaw"), in one command."""
        import json

        if not files:
            return {}
        # -fast2: stop at the image data (all read here is in front of it) and leave maker notes undecoded
        _, out, err = self.run(["-j", "-n", "-G1", "-a", "-fast2", *tags, *[str(f) for f in files]])
        try:
            rows = json.loads(out) if out.strip() else []
        except ValueError as exc:
            raise ExportError(f"exiftool gave unreadable JSON ({exc}); stderr: {err.strip()}") from exc
        by_name = {str(f): f for f in files}
        result: dict[Path, dict[str, Any]] = {}
        for row in rows:
            src = by_name.get(str(row.get("SourceFile", "")))
            if src is not None:
                result[src] = row
        return result
