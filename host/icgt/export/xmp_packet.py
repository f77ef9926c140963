"""One rdf:Description in a geotagged copy's XMP packet, so that ODM applies its per-make rules once.

ExifTool writes the copy's XMP with ``-api compact=onedesc``, but it still places some namespaces
(Camera Raw settings, ``crs``, and Photoshop history) in rdf:Description elements of their own, last,
so that they could move to extended XMP. ODM (opendm/photo.py) reads every Description in turn and,
after each one, applies its make rules to what it has read so far: for a DJI or Hasselblad file the
gimbal pitch gets +90 once per Description and the accuracy is doubled once per Description. A DJI
file with a ``crs`` block (DJI X3 files carry one) would be read at 180 deg pitch instead of 90.
ExifTool has no option to merge these blocks, so this module does it after ExifTool wrote the copy:
the Descriptions (all with the same rdf:about) become one holding every property and namespace
declaration, with the literal prefixes kept (ODM's xmltodict reads prefixes as written). A packet
whose Descriptions cannot be merged without changing a property (two values for one property,
one prefix for two namespaces, different rdf:about) is left as it is and the caller says so.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from lxml import etree

__all__ = ["XMP_APP1_HEADER", "MergeResult", "merge_descriptions", "merge_descriptions_in_jpeg", "xmp_span"]

XMP_APP1_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
_RDF = "http://www.w3.org/1999/02/22-rdf-syntax-ns#"
_ABOUT = f"{{{_RDF}}}about"
_MAX_SEGMENT = 0xFFFF - 2  # a JPEG segment's payload after its 2-byte length


@dataclass(frozen=True, slots=True)
class MergeResult:
    """What `merge_descriptions` did: ``merged`` Descriptions made one (0: nothing to do), or why not."""

    merged: int
    refused: str | None = None


def xmp_span(data: bytes) -> tuple[int, int] | None:
    """(start, end) of the XMP packet in a JPEG's standard-XMP APP1 segment (searched in its first MiB), or None."""
    i = data.find(XMP_APP1_HEADER, 0, 1 << 20)
    if i < 4 or data[i - 4 : i - 2] != b"\xff\xe1":
        return None
    return i + len(XMP_APP1_HEADER), min(len(data), i - 2 + int.from_bytes(data[i - 2 : i], "big"))


def _wrapper_span(packet: bytes) -> tuple[int, int] | None:
    start = packet.find(b"<x:xmpmeta")
    close = packet.find(b"</x:xmpmeta>")
    if start < 0 or close < start:
        return None
    return start, close + len(b"</x:xmpmeta>")


def merge_descriptions(packet: bytes) -> tuple[bytes, MergeResult]:
    """(the packet with its top-level rdf:Description elements merged into one, what was done)."""
    span = _wrapper_span(packet)
    if span is None:
        return packet, MergeResult(0, "no x:xmpmeta element")
    try:
        root = etree.fromstring(packet[span[0] : span[1]], etree.XMLParser(resolve_entities=False, no_network=True))
    except etree.XMLSyntaxError as exc:
        return packet, MergeResult(0, f"the XMP is not well-formed XML ({exc})")
    rdf = root.find(f"{{{_RDF}}}RDF")
    if rdf is None:
        return packet, MergeResult(0, "no rdf:RDF element")
    descs = rdf.findall(f"{{{_RDF}}}Description")
    if len(descs) < 2:
        return packet, MergeResult(0)
    abouts = {d.get(_ABOUT, "") for d in descs}
    if len(abouts) > 1:
        return packet, MergeResult(0, f"the rdf:Description elements describe different resources {sorted(abouts)}")
    nsmap: dict[str, str] = {}
    for d in descs:
        for prefix, uri in d.nsmap.items():
            if prefix is None:  # XMP names every namespace; a default one would change what names mean
                return packet, MergeResult(0, "a default namespace is declared")
            if nsmap.setdefault(prefix, uri) != uri:
                return packet, MergeResult(0, f"prefix {prefix!r} stands for two namespaces")
    merged = etree.Element(f"{{{_RDF}}}Description", nsmap=nsmap)
    merged.set(_ABOUT, abouts.pop())
    merged.text = descs[0].text
    merged.tail = descs[-1].tail
    seen: set[str] = set()
    for d in descs:
        for raw_key, value in d.attrib.items():
            key = str(raw_key)
            if key == _ABOUT:
                continue
            if key in seen:
                return packet, MergeResult(0, f"property {key} is in two rdf:Description elements")
            seen.add(key)
            merged.set(key, value)
        for child in list(d):
            tag = child.tag if isinstance(child.tag, str) else ""
            if tag and tag in seen:
                return packet, MergeResult(0, f"property {tag} is in two rdf:Description elements")
            seen.add(tag)
            merged.append(child)
    index = list(rdf).index(descs[0])
    for d in descs:
        rdf.remove(d)
    rdf.insert(index, merged)
    body = etree.tostring(root, encoding="utf-8")
    new = _refit(packet, span, body)
    return new, MergeResult(len(descs))


def _refit(packet: bytes, span: tuple[int, int], body: bytes) -> bytes:
    """The packet with its x:xmpmeta element replaced, keeping its length where the padding allows."""
    head, tail = packet[: span[0]], packet[span[1] :]
    grow = len(body) - (span[1] - span[0])
    end = tail.rfind(b"<?xpacket end")
    if end < 0:
        return head + body + tail
    pad, rest = tail[:end], tail[end:]
    if pad.strip() == b"":  # ExifTool's padding: whitespace that may grow or shrink freely
        pad = pad + b" " * (-grow) if grow <= 0 else pad[: max(1, len(pad) - grow)]
    return head + body + pad + rest


def merge_descriptions_in_jpeg(path: Path) -> MergeResult:
    """Merge the Descriptions of the JPEG's XMP packet (APP1) in place; what was done."""
    data = path.read_bytes()
    where = xmp_span(data)
    if where is None:
        return MergeResult(0)
    start, end = where
    packet, result = merge_descriptions(data[start:end])
    if not result.merged:
        return result
    payload = XMP_APP1_HEADER + packet
    if len(payload) > _MAX_SEGMENT:
        return MergeResult(0, f"the merged XMP ({len(payload)} bytes) does not fit one JPEG segment")
    segment = b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload
    seg_start = start - len(XMP_APP1_HEADER) - 4
    path.write_bytes(data[:seg_start] + segment + data[end:])
    return result
