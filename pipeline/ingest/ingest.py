"""The ingest stage: load one scan folder, validate it, convert it to head-frame millimetres and
repair what is safe to repair (:func:`ingest_scan`).

The mesh and texture readers are in :mod:`pipeline.io.load` (formats in :mod:`pipeline.io.formats`);
the head frame and its checks in :mod:`pipeline.geometry.frame`; the repairs in
:mod:`pipeline.ingest.repair`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from pipeline.errors import ScanError
from pipeline.ingest.repair import RepairSettings
from pipeline.io.formats.common import Limits
from pipeline.io.load import load_mesh_file, load_texture
from pipeline.io.scan import DEFAULT_MAX_YAML_BYTES, one_line
from pipeline.settings import Settings, setting

_MIB = 2**20


@dataclass(frozen=True)
class IngestSettings(Settings):
    """Every limit and threshold of the ingest stage (the ``ingest:`` block of params.yaml);
    defaults here, values checked by :mod:`pipeline.settings` (type, range, finite, no unknown keys).

    Attributes
    ----------
    max_file_mb, max_yaml_bytes, max_vertices, max_faces, max_texture_pixels
        Resource limits (see :class:`Limits`).
    head_size_mm : (2,) float
        Accepted range of the largest bounding-box side, mm.
    eye_separation_mm : (2,) float
        Accepted distance between the eye hints, mm.
    float32_tolerance_mm : float
        Largest float32 step accepted at the largest coordinate, mm.
    max_hint_distance_mm : float
        Largest distance from an eye hint to the mesh surface, mm.
    merge_tolerance_mm, degenerate_area_mm2, max_degenerate_fraction, debris_max_fraction,
    eye_radius_mm, max_eye_region_removed_fraction
        See :class:`pipeline.ingest.repair.RepairSettings`.
    flip_inward_winding : bool
        Flip all faces when the faces around the eyes point backward (inward winding);
        when False such a scan is refused.
    max_json_mb : float
        Largest GLB JSON chunk, MiB.
    max_memory_mb : float
        Address-space bound (``RLIMIT_AS``) the ingest stage sets on itself, MiB; 0 for none.
        The header checks refuse over-limit files long before this; it is the backstop.
    """

    block: ClassVar[str] = "ingest"

    # the defaults are the readers' and the repair's own (one definition each)
    max_file_mb: float = setting(Limits.max_file_bytes / _MIB, gt=0)
    max_yaml_bytes: int = setting(DEFAULT_MAX_YAML_BYTES, ge=1)
    max_vertices: int = setting(Limits.max_vertices, ge=3)
    max_faces: int = setting(Limits.max_faces, ge=1)
    max_texture_pixels: int = setting(Limits.max_texture_pixels, ge=1)
    head_size_mm: tuple[float, float] = setting((40.0, 1000.0), gt=0, ordered=True)
    eye_separation_mm: tuple[float, float] = setting((30.0, 120.0), gt=0, ordered=True)
    float32_tolerance_mm: float = setting(0.01, gt=0)
    max_hint_distance_mm: float = setting(15.0, gt=0)
    merge_tolerance_mm: float = setting(RepairSettings.merge_tolerance_mm, ge=0)
    degenerate_area_mm2: float = setting(RepairSettings.degenerate_area_mm2, ge=0)
    max_degenerate_fraction: float = setting(RepairSettings.max_degenerate_fraction, ge=0, le=1)
    debris_max_fraction: float = setting(RepairSettings.debris_max_fraction, ge=0, le=1)
    eye_radius_mm: float = setting(RepairSettings.eye_radius_mm, gt=0)
    max_eye_region_removed_fraction: float = setting(RepairSettings.max_eye_region_removed_fraction, ge=0, le=1)
    flip_inward_winding: bool = True
    max_json_mb: float = setting(Limits.max_json_bytes / _MIB, gt=0)
    max_memory_mb: float = setting(4096.0, ge=0)

    @property
    def limits(self) -> Limits:
        return Limits(max_file_bytes=int(self.max_file_mb * _MIB), max_vertices=int(self.max_vertices),
                      max_faces=int(self.max_faces), max_texture_pixels=int(self.max_texture_pixels),
                      max_json_bytes=int(self.max_json_mb * _MIB))

    @property
    def repair(self) -> RepairSettings:
        return RepairSettings(merge_tolerance_mm=self.merge_tolerance_mm,
                              degenerate_area_mm2=self.degenerate_area_mm2,
                              max_degenerate_fraction=self.max_degenerate_fraction,
                              debris_max_fraction=self.debris_max_fraction,
                              eye_radius_mm=self.eye_radius_mm,
                              max_eye_region_removed_fraction=self.max_eye_region_removed_fraction)


@dataclass
class IngestResult:
    """A validated, repaired scan in the head frame (mm).

    Attributes
    ----------
    mesh : dict of numpy.ndarray
        ``V`` (n,3) float64, ``F`` (m,3) int64, optional ``UV`` (k,2) + ``FUV`` (m,3), ``VC`` (n,3) uint8.
    texture : PIL.Image.Image or None
    texture_png_bytes : bytes or None
        The texture file's own bytes when it already is a PNG (copied unchanged).
    scan : dict
        Contents of ``scan.json`` (``texture`` is ``"texture.png"`` or None).
    metrics : dict
    """

    mesh: dict
    texture: object
    texture_png_bytes: bytes | None
    scan: dict
    metrics: dict


def source_sha256(folder, files) -> str:
    """SHA-256 over the (relative path, content hash) of every file read, sorted by path."""
    import hashlib

    folder = Path(folder).resolve()
    outer = hashlib.sha256()
    for rel, p in sorted({(Path(f).resolve().relative_to(folder).as_posix(), Path(f).resolve()) for f in files}):
        h = hashlib.sha256()
        with open(p, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 22), b""):
                h.update(chunk)
        outer.update(f"{rel}\0{h.hexdigest()}\n".encode())
    return outer.hexdigest()


def ingest_scan(folder, settings: IngestSettings = IngestSettings()) -> IngestResult:
    """Load, validate, convert to head-frame mm and safely repair one scan folder.

    Parameters
    ----------
    folder : str or os.PathLike
        The scan folder (``scan.yaml`` + mesh [+ texture]); only files it names are read.
    settings : IngestSettings

    Returns
    -------
    IngestResult

    Raises
    ------
    pipeline.errors.ScanError
        For any bad input, naming the file and the problem.
    """
    from pipeline.io.scan import read_sidecar

    spec = read_sidecar(folder, settings.max_yaml_bytes)
    try:
        return _ingest(folder, spec, settings)
    except MemoryError:
        raise ScanError(spec.mesh, "ran out of memory ingesting this mesh (the stage's address-space bound, "
                                   "ingest.max_memory_mb): a malformed file, or limits too high for the bound") from None
    except OverflowError as exc:
        raise ScanError(spec.mesh, f"a number is too large ({one_line(exc)[:80]})") from None


def _ingest(folder, spec, settings: IngestSettings) -> IngestResult:
    from pipeline.geometry import frame
    from pipeline.ingest import repair

    limits = settings.limits
    loaded = load_mesh_file(spec.mesh, spec.folder, limits)
    files = [spec.sidecar, *loaded.files_read]
    n_in, m_in = len(loaded.V) + loaded.merged_vertices, len(loaded.F)
    mesh_file = spec.mesh
    V = frame.to_head_frame(loaded.V, spec.units, spec.up_axis, spec.forward_axis)
    loaded.V = None
    hints = {s: frame.to_head_frame(h, spec.units, spec.up_axis, spec.forward_axis) for s, h in spec.hints.items()}
    step = frame.check_float32(V, mesh_file, settings.float32_tolerance_mm)
    frame.check_head_size(V, spec.units, mesh_file, settings.head_size_mm, hints=hints,
                          separation_mm=settings.eye_separation_mm)
    separation = frame.check_eye_layout(hints["left"], hints["right"], spec.sidecar, settings.eye_separation_mm)
    fixed = repair.repair_mesh(V, loaded.F, hints, settings.repair, path=mesh_file)
    fixed.counts["merged_vertices"] += loaded.merged_vertices
    del V
    loaded.F = None                              # the repaired F replaces it (memory at the limits)
    V, F = fixed.V, fixed.F
    if len(V) > limits.max_vertices:             # an STL soup's vertices are only counted once merged
        raise ScanError(mesh_file, f"{len(V)} vertices after merging duplicates, over the limit of "
                                   f"{limits.max_vertices} (ingest.max_vertices)")
    # texture coordinates and colours follow the kept faces / vertices
    UV = FUV = None
    if loaded.UV is not None:
        # every face kept and every UV row used (the usual scan): the arrays as loaded, no copies
        FUV_all = loaded.FUV if len(fixed.face_index) == len(loaded.FUV) else loaded.FUV[fixed.face_index]
        used = np.zeros(len(loaded.UV), dtype=bool)
        used[FUV_all.ravel()] = True
        if used.all():
            UV, FUV = loaded.UV, FUV_all.astype(np.int64, copy=False)
        else:
            remap = np.cumsum(used) - 1
            UV, FUV = loaded.UV[used], remap[FUV_all].astype(np.int64)
            del remap
        loaded.UV = loaded.FUV = None
        del FUV_all, used
    VC = loaded.VC[fixed.vertex_index] if loaded.VC is not None else None
    hint_dist = {}
    edges = repair.face_longest_edges(V, F)
    for side, h in hints.items():
        d = repair.point_surface_distance(V, F, h, edges)
        hint_dist[side] = round(d, 4)
        if d > settings.max_hint_distance_mm:
            raise ScanError(spec.sidecar, f"eyes.{side}.hint is {d:.1f} mm from the mesh surface, over the limit "
                                          f"of {settings.max_hint_distance_mm:g} mm (wrong hint, units or axes?)")
    normal_z = sum(float(repair.mean_normal_near(V, F, h, settings.eye_radius_mm)[2]) for h in hints.values())
    flipped = False
    if normal_z < 0:
        if not settings.flip_inward_winding:
            raise ScanError(mesh_file, "faces around the eyes point backward (-Z): inward winding or wrong "
                                       "forward_axis")
        shared = FUV is F                        # a PLY's per-vertex UVs: one flipped copy serves both
        F = F[:, ::-1].copy()
        if FUV is not None:
            FUV = F if shared else FUV[:, ::-1].copy()
        flipped = True
    # texture
    texture = png_bytes = None
    tex_src = spec.texture or loaded.texture_path
    tex_label = tex_src if tex_src is not None else f"{mesh_file} (embedded texture)"
    if tex_src is not None or loaded.texture_bytes is not None:
        if UV is None:
            raise ScanError(tex_label, f"a texture is given but the mesh {mesh_file.name} has no texture coordinates")
        texture = load_texture(tex_src if tex_src is not None else loaded.texture_bytes, limits, name=tex_label)
        if tex_src is not None:
            files.append(tex_src)
            if texture.info.get("source_format") == "PNG" and texture.info.get("source_mode") in ("RGB", "RGBA"):
                png_bytes = Path(tex_src).read_bytes()
    mesh = {"V": V, "F": F}
    if UV is not None:
        mesh.update(UV=UV, FUV=FUV)
    if VC is not None:
        mesh["VC"] = VC
    scan = {
        "name": Path(folder).name or spec.folder.name,
        "source_sha256": source_sha256(spec.folder, files),
        "licence": spec.licence,
        # "open" only where the user declared it: an undeclared scan keeps the same bytes
        "eyes": {s: {"hint": [float(x) for x in hints[s]], **({"open": True} if s in spec.open_eyes else {})}
                 for s in ("left", "right")},
        "texture": "texture.png" if texture is not None else None,
        "units_in": spec.units,
        "up_axis_in": spec.up_axis,
        "forward_axis_in": spec.forward_axis,
    }
    if spec.eye_size is not None:             # absent: the project's eye size (and the same bytes)
        scan["eye_size"] = spec.eye_size
    lo, hi = frame.bounds(V)
    metrics = {
        "mesh_file": mesh_file.name,
        "vertices_in": n_in, "faces_in": m_in,
        "vertices_out": int(len(V)), "faces_out": int(len(F)),
        "polygons_triangulated": loaded.polygons_triangulated,
        "repairs": fixed.counts,
        "edges": fixed.edges,
        "flipped_winding": flipped,
        "eye_region": fixed.eye_region,
        "hint_surface_distance_mm": hint_dist,
        "eye_hint_separation_mm": round(separation, 3),
        "bbox_min_mm": [round(float(x), 4) for x in lo],
        "bbox_max_mm": [round(float(x), 4) for x in hi],
        "float32_step_mm": step,
        "has_uv": UV is not None,
        "uv_count": 0 if UV is None else int(len(UV)),
        "uv_outside_unit_square_fraction": 0.0 if UV is None else
        round(float(np.mean(np.any((UV < 0) | (UV > 1), axis=1))), 6),
        "has_vertex_colors": VC is not None,
        "texture_size": list(texture.size) if texture is not None else None,
        "unknown_sidecar_keys": list(spec.unknown_keys),
        "files_read": sorted(Path(f).resolve().relative_to(spec.folder).as_posix() for f in set(files)),
    }
    return IngestResult(mesh=mesh, texture=texture, texture_png_bytes=png_bytes, scan=scan, metrics=metrics)
