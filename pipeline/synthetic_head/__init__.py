"""A procedural test head that behaves like a real scan of a real head.

The head is one parametric surface over a regular ``(t, y)`` grid: ``t`` is the
angle of a flat-fronted superellipse base curve in the horizontal plane (the
"skull" outline, about 150 mm wide), ``y`` the height in mm. Each grid point is
pushed along the base curve's horizontal outward normal by a depth ``h(t, y)``
(mm), so the surface is single-valued like a scanner's depth fusion, and the grid
triangulates into one connected sheet with its only boundary at the grid rim.

``h`` is the smooth maximum of two depths along the same ray:

* the eye surface: the outer intersection with the eyeball sphere (r1 drawn once per head
  from ``eye_radius_mm``, 11.7 +- 0.45 mm by default) joined by a smooth maximum with the
  paper's corneal sphere (r2 8 mm, apex 13.5 mm from the centre at r1 = 12, scaled with r1);
* the skin: a face depth field (forehead, brow ridge, orbits, nose, cheeks, lips,
  chin, jaw, neck) blended, near each eye, into a lid shell that follows the eye
  surface at ``+st + T(d)``, where ``d`` is the signed distance (mm) from an almond
  opening drawn in the eye's plane across the gaze and ``st`` the margin's standoff off
  the globe (0.5-0.9 mm between the canthi, growing to each corner's). ``T`` rises from 0
  at the margin to the lid thickness outside and drops behind the eyeball inside, so
  inside the almond the eye surface wins. The almond's corners (canthi) lie off the globe
  where UnityEyes' eye regions put them (medial ~8.6 mm, lateral ~4.5 mm in front of the
  centre); where the opening runs past the globe's silhouette a floor of tissue fills it
  (the caruncle medially, the fornix laterally). The fissure is 27 +- 1.7 mm wide and
  9.5 +- 1.5 mm high (docs/synthetic_head.md).

The smooth maximum rounds the lid/eye crease over ~1 mm, like a Poisson
reconstruction, while eye vertices away from the crease lie exactly on the
ground-truth spheres. Skin detail (pores, forehead lines, crow's feet, lower-lid
lines) is added to the skin depth only and fades out at the margin, so the
eyeball carries none. The colour texture is painted in the same ``(t, y)`` UV
space from the same fields.

Coordinates: head frame, mm, +Y up, +Z out of the face, +X = subject's left.

The shape model (base curve, eyes, depth fields) is in :mod:`.model`, the ground truth
(traced eyelid margins, hints) in :mod:`.truth`, the texture in :mod:`.paint`; this module
builds the mesh (:func:`make_synthetic_head`) and writes the scan folder.
"""

from __future__ import annotations

import dataclasses
import io
import json
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np

from pipeline.errors import ScanError
from pipeline.settings import SettingError, Settings, setting
from pipeline.synthetic_head.model import T_RANGE, Y_RANGE, HeadModel, base_curve, surface_points
from pipeline.synthetic_head.paint import SKIN_TONE_BASE, paint_texture
from pipeline.synthetic_head.truth import ground_truth

__all__ = ["SyntheticHead", "SyntheticHeadSettings", "EyeRadiusDraw", "make_synthetic_head", "write_scan_folder", "grid_shape",
           "identity_settings", "LICENCE", "EYE_SHAPES"]

LICENCE = "CC0-1.0 (procedural, eyerig)"
EYE_SHAPES = {"round": 0.0, "hooded": 1.0}


@dataclasses.dataclass(frozen=True)
class EyeRadiusDraw(Settings):
    """``synthetic_head.eye_radius_mm``: the population the eyeball radius r1 is drawn from, once
    per head (both eyes one size): a normal draw ``mean + sd * z``, ``z`` clipped to +-3."""

    block: ClassVar[str] = "synthetic_head.eye_radius_mm"

    mean: float = setting(11.7, ge=8, le=20)     # adults: 11.7 mm (axial length 23.4 +- 0.9 mm)
    sd: float = setting(0.45, ge=0, le=1)


@dataclasses.dataclass(frozen=True)
class SyntheticHeadSettings(Settings):
    """The ``synthetic_head:`` block of params.yaml (what :func:`make_synthetic_head` takes); its
    defaults and limits are the generator's: every value accepted here is generated."""

    block: ClassVar[str] = "synthetic_head"

    seed: int = setting(7, ge=0, le=2**32 - 1)                   # drives every shape detail
    target_triangles: int = setting(350_000, ge=200, le=5_000_000)  # ~0.7 mm vertex spacing at 350k
    eye_shape: Literal["round", "hooded"] | float = "round"      # or a hoodedness in [0, 1]
    eye_spacing_mm: float = setting(63.0, ge=40, le=90)          # interpupillary distance
    noise_mm: float = setting(0.02, ge=0, le=1)                  # scanner noise along normals (0 = off)
    texture_size: int = setting(2048, ge=16, le=8192)            # colour texture side (px)
    eye_radius_mm: EyeRadiusDraw = dataclasses.field(default_factory=EyeRadiusDraw)  # r1 ~ N(mean, sd), per head
    # identity: skin colour and age-like detail (pipeline/synthetic_head/paint.py, model.py)
    skin_tone: float = setting(SKIN_TONE_BASE, ge=0, le=1)       # melanin: 0 palest .. 1 darkest
    wrinkle_scale: float = setting(1.0, ge=0, le=3)              # depth of forehead lines, crow's feet, lid lines
    pore_scale: float = setting(1.0, ge=0, le=3)                 # depth of the pores
    # the asset's eye, written to scan.yaml as eye_size ("": left to remove_eyeballs.eye_size);
    # procedural identities say population: their globe is drawn from it, and the asset keeps it
    asset_eye_size: Literal["", "human", "population", "fitted"] = ""

    def validate(self) -> None:
        if isinstance(self.eye_shape, float) and not 0.0 <= self.eye_shape <= 1.0:
            raise SettingError("eye_shape", f"must be round, hooded or a number in [0, 1] (got {self.eye_shape:g})")


def identity_settings(params: dict, name: str, source="params.yaml") -> SyntheticHeadSettings:
    """Identity ``name``'s settings: the ``synthetic_head:`` block of the params mapping with its
    ``identities:`` entry (the keys that differ) over it.

    Raises ScanError (one line naming ``source`` and ``identities.<name>.<key>``) for a missing
    identity, an unknown key or a bad value.
    """
    idents = params.get("identities") or {}
    if not isinstance(idents, dict):
        raise ScanError(source, "identities must be a mapping of name -> synthetic_head keys")
    if name not in idents:
        raise ScanError(source, f"identities has no {name!r} (known: {', '.join(map(str, idents)) or 'none'})")
    entry = idents[name] if idents[name] is not None else {}
    if not isinstance(entry, dict):
        raise ScanError(source, f"identities.{name} must be a mapping of synthetic_head keys")
    base = params.get("synthetic_head") or {}
    if not isinstance(base, dict):
        raise ScanError(source, "synthetic_head must be a mapping of settings")
    known = set(SyntheticHeadSettings.keys())
    for k in entry:              # named as the identity's key, not the block's, when unknown
        if k not in known:
            raise ScanError(source, f"identities.{name}.{k} is an unknown key (known: "
                                    f"{', '.join(SyntheticHeadSettings.keys())})")
    return SyntheticHeadSettings.from_params({**base, **entry}, source=source, block=f"identities.{name}")


# ----------------------------------------------------------------------------- API

@dataclasses.dataclass
class SyntheticHead:
    """A generated head.

    Attributes
    ----------
    V : (n, 3) float64
        Vertices, mm, head frame.
    F : (m, 3) int64
        Triangles, counter-clockwise seen from outside.
    UV : (n, 2) float64
        Per-vertex texture coordinates in [0, 1], origin bottom-left.
    texture : (H, W, 3) uint8
        Colour texture (row 0 = top, i.e. v = 1).
    ground_truth : dict
        The ``ground_truth.json`` content (see module docs / DESIGN).
    hints : dict
        ``{"left": [x, y, z], "right": [x, y, z]}`` eye hints for ``scan.yaml``.
    grid_shape : tuple
        ``(n_y, n_t)`` of the parametric grid (vertex ``i`` = row ``i // n_t``).
    """

    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray
    texture: np.ndarray
    ground_truth: dict
    hints: dict
    grid_shape: tuple


def _arc_length():
    t = np.linspace(-T_RANGE, T_RANGE, 2001)
    x, z, _, _ = base_curve(t)
    return float(np.sum(np.hypot(np.diff(x), np.diff(z))))


def grid_shape(target_triangles: int) -> tuple[int, int]:
    """Grid ``(n_y, n_t)`` whose triangle count ``2 (n_y-1)(n_t-1)`` is closest to the target."""
    target_triangles = int(target_triangles)
    aspect = _arc_length() / (Y_RANGE[1] - Y_RANGE[0])
    cells = target_triangles / 2.0
    ny = max(int(round(np.sqrt(cells / aspect))), 2)
    nt = max(int(round(cells / ny)), 2)
    return ny + 1, nt + 1


def _grid_faces(ny, nt):
    idx = np.arange(ny * nt, dtype=np.int64).reshape(ny, nt)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    # rows go up in y, columns go toward +x: (a, b, d) is CCW seen from outside (+z)
    return np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def _normals(P):
    """Grid vertex normals (ny, nt, 3) from central differences of the grid."""
    dt = np.gradient(P, axis=1)
    dy = np.gradient(P, axis=0)
    n = np.cross(dt, dy)
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)


def make_synthetic_head(settings: SyntheticHeadSettings | None = None, *, skin_detail: float = 1.0,
                        **fields) -> SyntheticHead:
    """Generate the procedural test head.

    Parameters
    ----------
    settings : SyntheticHeadSettings, optional
        The ``synthetic_head:`` block (seed, target_triangles, eye_shape, eye_spacing_mm,
        noise_mm, texture_size, eye_radius_mm, skin_tone, wrinkle_scale, pore_scale; see its
        fields), or one identity's (that block with an ``identities:`` entry over it). None: its defaults, the same as
        params.yaml's. Every value it accepts is generated: its checks are the only limits.
    skin_detail : float
        Scale of all the fine skin detail, on top of ``wrinkle_scale`` and ``pore_scale``
        (1 = nominal, 0 = none); not a params.yaml setting.
    **fields
        Settings fields that replace the ones of ``settings`` (``seed=3, texture_size=64``),
        checked by :class:`SyntheticHeadSettings` (a ``SettingError``, a ValueError, names the
        bad one).

    Returns
    -------
    SyntheticHead
    """
    s = settings if settings is not None else SyntheticHeadSettings()
    if fields:
        s = dataclasses.replace(s, **fields)
    hood = EYE_SHAPES[s.eye_shape] if isinstance(s.eye_shape, str) else float(s.eye_shape)
    seed, target_triangles, eye_spacing_mm, noise_mm = s.seed, s.target_triangles, s.eye_spacing_mm, s.noise_mm
    texture_size, radius_draw = s.texture_size, (s.eye_radius_mm.mean, s.eye_radius_mm.sd)
    model = HeadModel(seed, hood, eye_spacing_mm, skin_detail, radius_draw, wrinkle_scale=s.wrinkle_scale,
                      pore_scale=s.pore_scale, skin_tone=s.skin_tone)
    ny, nt = grid_shape(target_triangles)
    tv = np.linspace(-T_RANGE, T_RANGE, nt)
    yv = np.linspace(Y_RANGE[0], Y_RANGE[1], ny)
    T, Y = np.meshgrid(tv, yv)
    base = tuple(np.broadcast_to(b, T.shape).ravel() for b in base_curve(tv))
    f = model.fields(T.ravel(), Y.ravel(), detail=True, base=base)
    P = surface_points(f, Y.ravel(), f["h"]).reshape(ny, nt, 3)
    if noise_mm > 0:
        nrng = np.random.default_rng([seed, 1])
        P = P + _normals(P) * nrng.normal(0.0, float(noise_mm), size=(ny, nt, 1))
    V = P.reshape(-1, 3)
    F = _grid_faces(ny, nt)
    UV = np.stack([(T.ravel() + T_RANGE) / (2 * T_RANGE),
                   (Y.ravel() - Y_RANGE[0]) / (Y_RANGE[1] - Y_RANGE[0])], 1)
    texture = paint_texture(model, int(texture_size))
    gt, hints = ground_truth(model, np.random.default_rng([seed, 2]), target_triangles)
    gt["skin_detail_amplitude_mm"] = round(float(np.abs(f["detail"]).max()), 5)
    gt["skin_detail_rms_mm"] = round(float(np.sqrt(np.mean(f["detail"][f["detail"] != 0] ** 2))), 5) \
        if np.any(f["detail"] != 0) else 0.0
    gt["noise_mm"] = float(noise_mm)
    gt["mesh"] = {"file": "scan.ply", "n_vertices": int(len(V)), "n_faces": int(len(F))}
    return SyntheticHead(V=V, F=F, UV=UV, texture=texture, ground_truth=gt, hints=hints,
                         grid_shape=(ny, nt))


# ----------------------------------------------------------------------------- writing

def ply_bytes(V, F, UV, texture_name="texture.png") -> bytes:
    """Binary little-endian PLY: float32 x y z s t per vertex, int32 triangles."""
    V = np.asarray(V)
    F = np.asarray(F)
    vert = np.empty(len(V), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("s", "<f4"), ("t", "<f4")])
    vert["x"], vert["y"], vert["z"] = V[:, 0], V[:, 1], V[:, 2]
    vert["s"], vert["t"] = UV[:, 0], UV[:, 1]
    face = np.empty(len(F), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"] = 3
    face["v"] = F
    header = ("ply\nformat binary_little_endian 1.0\ncomment eyerig synthetic head (mm, +Y up, +Z forward)\n"
              f"comment TextureFile {texture_name}\n"
              f"element vertex {len(V)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property float s\nproperty float t\n"
              f"element face {len(F)}\nproperty list uchar int vertex_indices\nend_header\n")
    return header.encode("ascii") + vert.tobytes() + face.tobytes()


def png_bytes(image) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.asarray(image, dtype=np.uint8)).save(buf, format="PNG", compress_level=3)
    return buf.getvalue()


def scan_yaml_text(head: SyntheticHead, eye_size: str = "") -> str:
    """The head's ``scan.yaml``; ``eye_size`` (when given) becomes its asset eye's size."""
    import yaml

    data = {
        "mesh": "scan.ply",
        "texture": "texture.png",
        "units": "mm",
        "up_axis": "+Y",
        "forward_axis": "+Z",
        "eyes": {side: {"hint": [float(v) for v in head.hints[side]]} for side in ("left", "right")},
        "licence": LICENCE,
    }
    if eye_size:
        data["eye_size"] = eye_size
    return "# procedural synthetic head (eyerig); ground truth in ground_truth.json\n" + \
        yaml.safe_dump(data, sort_keys=False, default_flow_style=None)


def write_scan_folder(head: SyntheticHead, folder, eye_size: str = "") -> None:
    """Write ``scan.ply``, ``texture.png``, ``scan.yaml`` and ``ground_truth.json`` into ``folder``
    (``eye_size``: the settings' ``asset_eye_size``, written to scan.yaml when given).

    ``folder`` must exist (a stage passes the temporary folder of ``atomic_dir``).
    """
    folder = Path(folder)
    (folder / "scan.ply").write_bytes(ply_bytes(head.V, head.F, head.UV))
    (folder / "texture.png").write_bytes(png_bytes(head.texture))
    (folder / "scan.yaml").write_text(scan_yaml_text(head, eye_size), encoding="utf-8")
    (folder / "ground_truth.json").write_text(json.dumps(head.ground_truth, indent=1) + "\n",
                                              encoding="utf-8")
