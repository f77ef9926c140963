"""Merging an XMP packet's rdf:Description elements (icgt.export.xmp_packet): what is merged, what is refused."""

from __future__ import annotations

from icgt.export.xmp_packet import merge_descriptions

from .odm_rules import descriptions

HEAD = '<?xpacket begin="" id="W5M0MpCehiHzreSzNTczkc9d"?><x:xmpmeta xmlns:x="adobe:ns:meta/">'
RDF = '<rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
TAIL = "</rdf:RDF></x:xmpmeta>" + " " * 200 + '<?xpacket end="w"?>'


def packet(*descs: str) -> bytes:
    return (HEAD + RDF + "".join(descs) + TAIL).encode()


def app1(p: bytes) -> bytes:
    """As the first XMP packet of a file, for the ODM-rule reader."""
    return b"\xff\xd8" + p


def test_two_descriptions_become_one_with_prefixes_and_children_kept() -> None:
    p = packet(
        '<rdf:Description rdf:about="a" xmlns:dc="http://purl.org/dc/elements/1.1/" dc:format="image/jpeg">'
        "<dc:creator><rdf:Seq><rdf:li>me</rdf:li></rdf:Seq></dc:creator></rdf:Description>",
        '<rdf:Description rdf:about="a" xmlns:crs="http://ns.adobe.com/camera-raw-settings/1.0/" crs:Version="7.0"/>',
    )
    out, result = merge_descriptions(p)
    assert result.merged == 2 and result.refused is None
    assert len(out) == len(p)  # the padding took up the difference
    (desc,) = descriptions(app1(out))
    assert desc["@dc:format"] == "image/jpeg" and desc["@crs:Version"] == "7.0" and desc["@rdf:about"] == "a"
    assert b"<dc:creator><rdf:Seq><rdf:li>me</rdf:li></rdf:Seq></dc:creator>" in out  # a structure moved whole
    assert out.startswith(HEAD[:20].encode()) and out.rstrip().endswith(b'<?xpacket end="w"?>')


def test_what_cannot_be_merged_is_left_as_it_is_and_said() -> None:
    ns = 'xmlns:dc="http://purl.org/dc/elements/1.1/"'
    cases = {
        "different resources": ('<rdf:Description rdf:about="a"/>', '<rdf:Description rdf:about="b"/>'),
        "two rdf:Description": (
            f'<rdf:Description rdf:about="" {ns} dc:format="x"/>',
            f'<rdf:Description rdf:about="" {ns} dc:format="y"/>',
        ),
        "two namespaces": (
            f'<rdf:Description rdf:about="" {ns} dc:format="x"/>',
            '<rdf:Description rdf:about="" xmlns:dc="urn:other" dc:title="y"/>',
        ),
    }
    for why, descs in cases.items():
        p = packet(*descs)
        out, result = merge_descriptions(p)
        assert out == p and result.merged == 0 and result.refused is not None and why in result.refused, why
    one = packet('<rdf:Description rdf:about=""/>')
    assert merge_descriptions(one) == (one, merge_descriptions(one)[1]) and merge_descriptions(one)[1].merged == 0
    assert merge_descriptions(b"<rdf:RDF/>")[1].refused == "no x:xmpmeta element"
