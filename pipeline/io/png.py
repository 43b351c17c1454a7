"""PNG files without time or text metadata, so identical pixels give identical bytes.

Blender writes ``tEXt`` chunks (Date, Time, RenderTime, File, ...) and PNG writers may add a
``tIME`` chunk; both change on every run. :func:`strip_png_metadata` rewrites a PNG keeping
every chunk except ``tIME``, ``tEXt``, ``zTXt`` and ``iTXt`` (the pixels, palette and colour
chunks are copied byte for byte, nothing is re-encoded).
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

SIGNATURE = b"\x89PNG\r\n\x1a\n"
DROPPED = frozenset({b"tIME", b"tEXt", b"zTXt", b"iTXt"})


def png_chunks(data: bytes):
    """``(type, start, end)`` of every chunk of PNG ``data`` (ValueError when it is not a PNG)."""
    if not data.startswith(SIGNATURE):
        raise ValueError("not a PNG file")
    pos, out = len(SIGNATURE), []
    while pos < len(data):
        if pos + 8 > len(data):
            raise ValueError("truncated PNG chunk header")
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind = data[pos + 4:pos + 8]
        end = pos + 12 + length
        if end > len(data):
            raise ValueError(f"truncated PNG chunk {kind!r}")
        out.append((kind, pos, end))
        pos = end
        if kind == b"IEND":
            break
    return out


def strip_png_bytes(data: bytes) -> bytes:
    """``data`` without its time and text chunks."""
    chunks = png_chunks(data)
    return SIGNATURE + b"".join(data[a:b] for kind, a, b in chunks if kind not in DROPPED)


def strip_png_metadata(path) -> bool:
    """Rewrite the PNG at ``path`` in place without time/text chunks; True when it changed.

    For files a stage is still assembling (in its temporary folder), not for published outputs.
    """
    path = Path(path)
    data = path.read_bytes()
    clean = strip_png_bytes(data)
    if clean == data:
        return False
    tmp = path.with_name(f".{path.name}.strip-{os.getpid()}")
    tmp.write_bytes(clean)
    os.replace(tmp, path)
    return True
