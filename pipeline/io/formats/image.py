"""Which image formats a scan's texture may be, decided from its first bytes before any decoder runs.

A scan's colour texture (``scan.yaml`` ``texture:``, an MTL ``map_Kd`` or a GLB's embedded
image) is untrusted. Pillow picks a decoder from the content, not the name, and some of its
decoders hand the data to an external program (PostScript and EPS start Ghostscript, ``gs``).
So only :data:`TEXTURE_FORMATS` are decoded: the file's magic bytes are checked first
(:func:`sniff_texture`), and every ``Image.open`` on scan data is given that one format
(``formats=[...]``), so no other Pillow plugin ever sees the bytes. Anything else is refused in
one line naming the file and what the content is (``texture is PostScript, not PNG/JPEG/TIFF``).
"""

from __future__ import annotations

from pipeline.errors import ScanError

# Pillow format name -> the magic bytes it starts with
TEXTURE_FORMATS = {
    "PNG": (b"\x89PNG\r\n\x1a\n",),
    "JPEG": (b"\xff\xd8\xff",),
    "TIFF": (b"II*\x00", b"MM\x00*"),           # classic TIFF, little and big endian (no BigTIFF)
}
ALLOWED = "PNG/JPEG/TIFF"

# What a refused texture is, to name it in the message (first match wins); anything else is "unknown".
_KNOWN = (
    (b"%!PS-Adobe-", "PostScript"), (b"%!", "PostScript"), (b"\xc5\xd0\xd3\xc6", "EPS (binary PostScript)"),
    (b"%PDF", "PDF"), (b"/* XPM */", "XPM"), (b"! XPM2", "XPM"), (b"GIF87a", "GIF"), (b"GIF89a", "GIF"),
    (b"BM", "BMP"), (b"v/1\x01", "OpenEXR"), (b"\x00\x00\x00\x0cjP  ", "JPEG 2000"), (b"\xffO\xffQ", "JPEG 2000"),
    (b"II+\x00", "BigTIFF"), (b"MM\x00+", "BigTIFF"), (b"8BPS", "Photoshop (PSD)"), (b"icns", "ICNS"),
    (b"\x00\x00\x01\x00", "ICO"), (b"#?RADIANCE", "Radiance HDR"), (b"#?RGBE", "Radiance HDR"),
    (b"<svg", "SVG"), (b"<?xml", "XML"), (b"\x1f\x8b", "gzip"), (b"PK\x03\x04", "ZIP"),
    (b"DDS ", "DDS"), (b"qoif", "QOI"), (b"\x01\xda", "SGI"), (b"\x59\xa6\x6a\x95", "Sun raster"),
    (b"FORM", "IFF"), (b"SIMPLE  =", "FITS"), (b"#define", "XBM"),
)


def sniff_texture(data: bytes, label, what: str = "texture") -> str:
    """The Pillow format name of an allowed texture, from its first bytes; refuse anything else.

    Parameters
    ----------
    data : bytes
        The start of the file (at least 16 bytes when the file has them).
    label : str or pathlib.Path
        The file named in the error.
    what : str
        What the data is, for the message (``"texture"``, ``"GLB image 0"``).

    Returns
    -------
    str
        ``"PNG"``, ``"JPEG"`` or ``"TIFF"``: pass it as ``Image.open(..., formats=[it])``.

    Raises
    ------
    ScanError
        The content is another format (named when recognised) or empty.
    """
    head = bytes(data[:32])
    for fmt, magics in TEXTURE_FORMATS.items():
        if head.startswith(magics):
            return fmt
    if not head:
        raise ScanError(label, f"{what} is empty, not {ALLOWED}")
    found = next((name for magic, name in _KNOWN if head.startswith(magic)), None)
    if found is None and head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        found = "WebP"
    if found is None and len(head) > 2 and head[0] == 0x50 and head[1:2] in b"1234567" and head[2:3].isspace():
        found = "PNM"
    if found is None:
        found = f"an unknown format (first bytes {head[:8].hex(' ')})"
    raise ScanError(label, f"{what} is {found}, not {ALLOWED}; only those are decoded")
