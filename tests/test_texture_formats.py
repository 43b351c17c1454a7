"""Only PNG, JPEG and TIFF textures are decoded (issue 31): PostScript, EPS, PDF or XPM content under a
``.png`` name is refused from its first bytes, in one line naming the file and the format, and no
program is started (Pillow's EPS plugin runs Ghostscript, ``gs``), whether the texture is named by
``scan.yaml``, an MTL ``map_Kd`` or embedded in a GLB."""

from __future__ import annotations

import io
import re
import subprocess

import pytest

from fixtures import build_case, ingest
from fixtures.hostile import NOT_IMAGES, _not_image_texture, c_glb_postscript_image, c_mtl_postscript_as_png
from pipeline.errors import ScanError
from pipeline.io.load import load_texture


class _NoPrograms(Exception):
    pass


@pytest.fixture
def no_programs(monkeypatch):
    """Once called, any attempt to start a program is recorded and fails (Pillow's Ghostscript calls go
    through Popen). Called after the scan folder is built: building it imports trimesh, which runs lscpu."""
    started = []

    def refuse(self, args, *a, **k):
        started.append(args)
        raise _NoPrograms(f"a program was started: {args!r}")

    def arm():
        import trimesh  # noqa: F401  (its import runs a program; the stage imports it too)
        monkeypatch.setattr(subprocess.Popen, "__init__", refuse)
        monkeypatch.setattr("os.system", lambda cmd: started.append(cmd) or 1)
        return started
    return arm


ROUTES = [(_not_image_texture(kind), "skin.png", f"texture is {kind}, not PNG/JPEG/TIFF") for kind in NOT_IMAGES]
ROUTES += [(c_mtl_postscript_as_png, "skin.png", "texture is PostScript, not PNG/JPEG/TIFF"),
           (c_glb_postscript_image, "scan.glb", "GLB image 0 is PostScript, not PNG/JPEG/TIFF")]


@pytest.mark.parametrize("build,fname,problem", ROUTES, ids=[r[0].__name__[2:] for r in ROUTES])
def test_not_an_image_refused_before_any_decoder(tmp_path, capsys, no_programs, build, fname, problem):
    folder, params = build_case(build, tmp_path)
    started = no_programs()
    out = tmp_path / "out"
    rc = ingest(folder, out, params)
    err = capsys.readouterr().err
    assert started == []
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and fname in lines[0] and problem in lines[0], err
    assert not out.exists()


@pytest.mark.parametrize("kind", list(NOT_IMAGES))
def test_load_texture_refuses_other_formats(tmp_path, no_programs, kind):
    started = no_programs()
    path = tmp_path / "scan.png"
    path.write_bytes(NOT_IMAGES[kind])
    with pytest.raises(ScanError, match=re.escape(f"scan.png: texture is {kind}, not PNG/JPEG/TIFF")):
        load_texture(path)
    with pytest.raises(ScanError, match=re.escape(f"texture is {kind}")):
        load_texture(NOT_IMAGES[kind], name="embedded")
    assert started == []


@pytest.mark.parametrize("fmt,suffix", [("PNG", ".png"), ("JPEG", ".jpg"), ("TIFF", ".tif")])
def test_png_jpeg_tiff_still_decode(tmp_path, no_programs, fmt, suffix):
    from PIL import Image

    no_programs()
    path = tmp_path / f"skin{suffix}"
    Image.new("RGB", (8, 4), (200, 100, 50)).save(path, format=fmt)
    img = load_texture(path)
    assert img.size == (8, 4) and img.info["source_format"] == fmt
    buf = io.BytesIO()
    Image.new("RGB", (8, 4)).save(buf, format=fmt)
    assert load_texture(buf.getvalue(), name="embedded").info["source_format"] == fmt


def test_other_image_formats_named(tmp_path):
    from PIL import Image

    for fmt, name in (("GIF", "GIF"), ("BMP", "BMP"), ("WEBP", "WebP")):
        buf = io.BytesIO()
        Image.new("RGB", (8, 4)).save(buf, format=fmt)
        with pytest.raises(ScanError, match=f"texture is {name}, not PNG/JPEG/TIFF"):
            load_texture(buf.getvalue(), name="x.png")
