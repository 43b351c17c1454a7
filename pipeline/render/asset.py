"""What a render needs from a per-scan rigged asset, read with pxr + numpy (no Blender).

:func:`load_render_asset` reads ``rigged_assets/<scan>/<scan>.usda`` and ``build/<scan>/rig/rig.npz``
into a :class:`RenderAsset`, and :func:`posed_landmarks` / :func:`posed_lid_polygon` compute,
for a posed sample, exactly the points the Blender worker shows:

* eyelid landmarks: the skin mesh (``EyeRegion`` points, float32 in the file like Blender's
  import) posed with the lid shapes of ``rig.npz`` (UsdSkel inbetween evaluation,
  :func:`pipeline.rig.lids.evaluate_shapes`, which Blender reproduces with one shape key per
  stored pose), then ``(1 - t) V[a] + t V[b]`` on the stored margin edge ``(a, b, t)`` of each
  of the 12 landmarks (``landmarks.<side>.edge/t``). Rigs without edge/t (older or
  hand-made) fall back to the landmark curve's own blend shapes
  (:func:`pipeline.rig.landmarks.posed_eyelid_landmarks`).
* iris / pupil landmarks: ``Inner`` mesh vertices ``eyerig:landmarks:iris/pupil`` of each eye,
  with the eyeball blend shapes (pupil_dilate, pupil_constrict, iris_large, iris_small) applied
  in model space, taken to the head frame with the eye's ``geomBindTransform`` (rigid skinning,
  bind = rest) and rotated about the eye centre by the sample's eye rotation.
* the eyelid polygon of the pupil-in-lid rule: the posed 64-vertex lid loop
  (``loop_<side>`` in rig.npz; the 12 landmarks when the rig has no loop).

All positions are head-frame millimetres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.bake_file import read_displacement
from pipeline.io.rig_file import read_rig
from pipeline.rig import lids

SIDES = ("left", "right")
N_EYELID, N_IRIS, N_PUPIL = 12, 8, 8
N_LANDMARKS = N_EYELID + N_IRIS + N_PUPIL


def renderer_sources(root: Path | None = None) -> list[Path]:
    """The source files whose change invalidates rendered images: every project file the render
    stage runs (the import closure of ``stages/render.py``, :func:`pipeline.sources.stage_closure`,
    the same set dvc.yaml lists as its code deps), sorted. ``root``: the folder holding
    ``pipeline/`` and ``stages/`` (default: this installation's)."""
    from pipeline import sources

    root = sources.ROOT if root is None else Path(root)
    return [root / p for p in sorted(sources.stage_closure("render", root))]


def sources_digest(files, root: Path | None = None) -> str:
    """sha256 over ``files`` (paths relative to ``root`` and their bytes), in sorted order."""
    import hashlib

    from pipeline import sources

    root = sources.ROOT if root is None else Path(root)
    h = hashlib.sha256()
    for p in sorted(files):
        h.update(Path(p).relative_to(root).as_posix().encode() + b"\0")
        h.update(Path(p).read_bytes())
    return h.hexdigest()


@dataclass
class EyeAsset:
    """One eye of the asset.

    Attributes
    ----------
    center : (3,) float64        eye joint rest translation (eyeball centre), mm
    basis : (3, 3) float64       rows e_x, e_y, forward of the joint rest rotation
    bind : (4, 4) float64        geomBindTransform (row-vector convention: p_head = [p, 1] @ bind)
    radius : float               eyeball radius in the head frame, mm (the asset's metadata
                                 ``eyes.<side>.radius_mm``; else its eyeball's ``r1`` x the bind scale)
    inner_rest : (k, 3) float64  Inner mesh points (model space, mm)
    inner_shapes : dict          name -> (indices (j,) int64, offsets (j, 3) float64)
    iris : (8,) int64 ; pupil : (8,) int64   Inner vertex indices of the landmarks
    pupil_center : int           Inner vertex at the pupil centre (front pole, vertex 0)
    lm_edge : (12, 2) int64 | None ; lm_t : (12,) float64 | None   eyelid landmark edges
    loop : (L,) int64 | None     lid loop (skin vertex indices)
    eyeball_params : dict        the eyeball asset's geometry (customData eyerig.params, model mm)
    cornea_ior : float
    """

    side: str
    center: np.ndarray
    basis: np.ndarray
    bind: np.ndarray
    radius: float
    inner_rest: np.ndarray
    inner_shapes: dict
    iris: np.ndarray
    pupil: np.ndarray
    pupil_center: int
    lm_edge: np.ndarray | None
    lm_t: np.ndarray | None
    loop: np.ndarray | None
    eyeball_params: dict = field(default_factory=dict)
    cornea_ior: float = 1.376

    @property
    def forward(self) -> np.ndarray:
        return self.basis[2]

    def model_to_head(self, rotation) -> np.ndarray:
        """(4, 4) column-vector affine: eyeball model space -> head frame for an eye rotation."""
        R = np.asarray(rotation, np.float64)
        A = np.eye(4)
        A[:3, :3] = R @ self.bind[:3, :3].T
        A[:3, 3] = R @ (self.bind[3, :3] - self.center) + self.center
        return A


@dataclass
class RenderAsset:
    """Everything the sampler and the labeller need (see the module docstring)."""

    name: str
    usda: Path
    rig_npz: Path
    skin_rest: np.ndarray                 # (n, 3) float64
    skin_faces_edge_mm: float             # median edge length of the skin mesh
    lid_shapes: list                      # list of pipeline.rig.lids.BlendShape
    rig_arrays: dict
    eyes: dict                            # side -> EyeAsset
    max_pitch_deg: float = lids.MAX_PITCH_DEG
    displacement_amplitude_mm: float = 0.0
    variants: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)   # customData["eyerig"]: scan, licence, source_sha256, ...
    skin_faces: np.ndarray | None = None  # (m, 3) int64 skin triangles (polygons fanned), for pipeline/render/coverage.py

    def doubts(self) -> list[str]:
        """What the pipeline was not sure of when it built this asset (``eyes.<side>.doubts`` in
        its metadata, from remove_eyeballs and rig), as "<side> eye: <sentence>"."""
        eyes = self.metadata.get("eyes") or {}
        return [f"{side} eye: {d}" for side in ("left", "right")
                for d in ((eyes.get(side) or {}).get("doubts") or [])]

    def fingerprint(self) -> str:
        """sha256 of every file the render reads (for the config hash of a render folder).

        The asset layer with all its USD dependencies (the referenced eyeball layer, every
        texture and the files beside them, from ``UsdUtils.ComputeAllDependencies``), rig.npz,
        and the renderer's source (:func:`renderer_sources`, every module the render stage
        imports): a changed input or renderer invalidates the images of a resumable render
        folder. The render settings join it in ``pipeline.render.run.config_hash``.
        """
        import hashlib

        from pxr import UsdUtils

        layers, assets, _ = UsdUtils.ComputeAllDependencies(str(self.usda))
        files = {Path(layer.realPath) for layer in layers if layer.realPath}
        files |= {Path(a) for a in assets}
        files |= {q for a in assets for q in Path(a).parent.iterdir()}   # e.g. sclera_bump.png
        files |= {self.usda, self.rig_npz}
        h = hashlib.sha256()
        for p in sorted(files):
            if p.is_file():
                h.update(p.name.encode())
                h.update(p.read_bytes())
        h.update(sources_digest(renderer_sources()).encode())
        return h.hexdigest()


def _find_asset(asset_dir: Path) -> Path:
    if asset_dir.is_file() and asset_dir.suffix == ".usda":
        return asset_dir
    if not asset_dir.is_dir():
        raise ScanError(asset_dir, "rigged asset folder not found")
    cand = asset_dir / f"{asset_dir.name}.usda"
    if cand.is_file():
        return cand
    found = sorted(asset_dir.glob("*.usda"))
    if len(found) != 1:
        raise ScanError(asset_dir, f"expected one <scan>.usda, found {len(found)}")
    return found[0]


def _plain(v):
    """A USD customData value as plain Python (dicts, lists, str, numbers)."""
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (str, bool, int, float)) or v is None:
        return v
    try:
        return [_plain(x) for x in v]
    except TypeError:
        return str(v)


def _displacement_amplitude(usda: Path) -> float:
    """99th percentile of |displacement| (mm) of textures/displacement.exr (0 if absent)."""
    p = usda.parent / "textures" / "displacement.exr"
    if not p.is_file():
        return 0.0
    d = np.abs(read_displacement(p))
    return float(np.percentile(d, 99))


def load_render_asset(asset_dir, rig_dir) -> RenderAsset:
    """Read the render inputs of one scan.

    Parameters
    ----------
    asset_dir : path   ``rigged_assets/<scan>/`` (or the .usda itself)
    rig_dir : path     ``build/<scan>/rig/`` (or its rig.npz), read with pipeline.io.rig_file

    Raises
    ------
    ScanError  when a file is missing or the asset lacks a part the render needs.
    """
    asset_dir, rig_dir = Path(asset_dir), Path(rig_dir)
    usda = _find_asset(asset_dir)
    from pxr import Usd, UsdGeom, UsdSkel

    try:
        stage = Usd.Stage.Open(str(usda))
    except Exception as exc:  # noqa: BLE001 -- pxr raises Tf.ErrorException on a broken layer
        msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        raise ScanError(usda, f"USD stage could not be opened ({msg.strip()})") from None
    if stage is None:
        raise ScanError(usda, "USD stage could not be opened")
    root = stage.GetDefaultPrim()
    if not root:
        raise ScanError(usda, "no default prim")
    rp = root.GetPath().pathString
    skin_prim = stage.GetPrimAtPath(rp + "/EyeRegion")
    if not skin_prim or not skin_prim.IsA(UsdGeom.Mesh):
        raise ScanError(usda, "no EyeRegion mesh")
    skin = UsdGeom.Mesh(skin_prim)
    V = np.asarray(skin.GetPointsAttr().Get(), np.float32).astype(np.float64)
    idx = np.asarray(skin.GetFaceVertexIndicesAttr().Get(), np.int64)
    cnt = np.asarray(skin.GetFaceVertexCountsAttr().Get(), np.int64)
    starts = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    a = idx
    b = idx.copy()
    tris = [idx[s + np.array([0, k, k + 1])] for s, c in zip(starts, cnt) for k in range(1, c - 1)]
    for s, c in zip(starts, cnt):          # next corner within each face (few thousand faces)
        b[s:s + c] = np.roll(idx[s:s + c], -1)
    edge_len = float(np.median(np.linalg.norm(V[a] - V[b], axis=1))) if len(a) else 0.0

    skel = UsdSkel.Skeleton(stage.GetPrimAtPath(rp + "/Skel"))
    if not skel:
        raise ScanError(usda, "no Skel skeleton")
    joints = [str(j) for j in skel.GetJointsAttr().Get()]
    rest = [np.array(m, np.float64) for m in (skel.GetRestTransformsAttr().Get() or [])]

    rig = read_rig(rig_dir, n_vertices=len(V), against="the asset")
    arrays, lid_shapes = rig.npz.arrays, rig.npz.shapes

    eyes = {}
    for side in SIDES:
        jname = f"head/eye_{side}"
        if jname not in joints or len(rest) != len(joints):
            raise ScanError(usda, f"skeleton has no joint {jname} with a rest transform")
        R = rest[joints.index(jname)]
        inner_p = stage.GetPrimAtPath(f"{rp}/Eyes/eye_{side}/Inner")
        if not inner_p:
            raise ScanError(usda, f"no Eyes/eye_{side}/Inner mesh (eyeball reference unresolved?)")
        inner_rest = np.asarray(UsdGeom.Mesh(inner_p).GetPointsAttr().Get(), np.float32).astype(np.float64)
        g = inner_p.GetAttribute("primvars:skel:geomBindTransform").Get()
        G = np.array(g, np.float64) if g is not None else R.copy()
        shapes = {}
        binding = UsdSkel.BindingAPI(inner_p)
        names = [str(n) for n in (binding.GetBlendShapesAttr().Get() or [])]
        for n, tgt in zip(names, binding.GetBlendShapeTargetsRel().GetTargets()):
            bs = UsdSkel.BlendShape(stage.GetPrimAtPath(tgt))
            off = np.asarray(bs.GetOffsetsAttr().Get(), np.float64)
            pi = bs.GetPointIndicesAttr().Get()
            pi = np.arange(len(off)) if pi is None else np.asarray(pi, np.int64)
            shapes[n] = (pi, off)
        lm = stage.GetPrimAtPath(f"{rp}/Landmarks/eye_{side}")
        src = lm if lm else inner_p
        iris = np.asarray(src.GetAttribute("eyerig:landmarks:iris").Get() or [], np.int64)
        pupil = np.asarray(src.GetAttribute("eyerig:landmarks:pupil").Get() or [], np.int64)
        if len(iris) != N_IRIS or len(pupil) != N_PUPIL:
            raise ScanError(usda, f"eye_{side}: expected {N_IRIS} iris and {N_PUPIL} pupil landmark "
                                  f"indices, found {len(iris)} and {len(pupil)}")
        if max(iris.max(), pupil.max()) >= len(inner_rest):
            raise ScanError(usda, f"eye_{side}: landmark index beyond the Inner mesh")
        pre = f"landmarks.{side}."                 # checked by read_rig
        edge, t, loop = arrays.get(pre + "edge"), arrays.get(pre + "t"), arrays.get(f"loop_{side}")
        basis = R[:3, :3] / np.linalg.norm(R[:3, :3], axis=1, keepdims=True)
        eb_meta = stage.GetPrimAtPath(f"{rp}/Eyes/eye_{side}").GetCustomDataByKey("eyerig") or {}
        eb_params = {k: float(v) for k, v in dict(eb_meta.get("params") or {}).items()}
        meta_eye = ((root.GetCustomDataByKey("eyerig") or {}).get("eyes") or {}).get(side) or {}
        scale = float(np.linalg.norm(G[0, :3]))     # the eyeball's sphere as placed (the asset's word)
        radius = float(meta_eye.get("radius_mm", eb_params.get("r1", 12.0) * scale))
        eyes[side] = EyeAsset(side=side, center=R[3, :3].copy(), basis=basis, bind=G,
                              radius=radius, inner_rest=inner_rest,
                              inner_shapes=shapes, iris=iris, pupil=pupil,
                              pupil_center=int(np.argmax(inner_rest[:, 2])),
                              lm_edge=None if edge is None else np.asarray(edge, np.int64),
                              lm_t=None if t is None else np.asarray(t, np.float64),
                              loop=None if loop is None else np.asarray(loop, np.int64),
                              eyeball_params=eb_params,
                              cornea_ior=float(eb_meta.get("cornea_ior", 1.376)))

    meta = root.GetCustomDataByKey("eyerig") or {}
    wr = meta.get("weight_rule") or {}
    max_pitch = float(wr.get("max_pitch_deg", lids.MAX_PITCH_DEG))
    vsets = {n: list(root.GetVariantSets().GetVariantSet(n).GetVariantNames())
             for n in root.GetVariantSets().GetNames()}
    name = str(meta.get("scan") or root.GetName())
    return RenderAsset(name=name, usda=usda.resolve(), rig_npz=rig.npz_path.resolve(), skin_rest=V,
                       skin_faces_edge_mm=edge_len, lid_shapes=lid_shapes, rig_arrays=arrays,
                       eyes=eyes, max_pitch_deg=max_pitch,
                       displacement_amplitude_mm=_displacement_amplitude(usda), variants=vsets,
                       metadata=_plain(meta), skin_faces=np.array(tris, np.int64).reshape(-1, 3))


# ------------------------------------------------------------------------------------ posing

def posed_skin(asset: RenderAsset, lid_weights: dict, indices=None) -> np.ndarray:
    """Skin points posed by the lid channel weights; only ``indices`` if given.

    Returns
    -------
    (n, 3) or (len(indices), 3) float64, head mm.
    """
    if indices is None:
        return lids.evaluate_shapes(asset.skin_rest, asset.lid_shapes, lid_weights)
    uniq, inv = np.unique(np.asarray(indices, np.int64), return_inverse=True)
    P = asset.skin_rest[uniq].copy()
    for s in asset.lid_shapes:
        w = lid_weights.get(s.name, 0.0)
        if w == 0.0 or len(s.point_indices) == 0:
            continue
        _, offs = s.knots()
        sub = lids.subshape_weights(s, w)
        pi = np.asarray(s.point_indices, np.int64)
        hit = np.flatnonzero(np.isin(pi, uniq))
        if len(hit):
            off = np.tensordot(sub, offs[1:, hit], axes=1)
            P[np.searchsorted(uniq, pi[hit])] += off
    return P[inv]


def inner_points(eye: EyeAsset, blend: dict, rotation, indices) -> np.ndarray:
    """Posed head-frame positions of Inner vertices ``indices``.

    Blend shapes (weights clamped to [0, 1]) in model space, then the bind transform, then
    the eye rotation ``rotation`` ((3, 3) head-frame matrix) about the eye centre.
    """
    idx = np.asarray(indices, np.int64)
    P = eye.inner_rest[idx].copy()
    for name, (pi, off) in eye.inner_shapes.items():
        w = min(max(float(blend.get(name, 0.0)), 0.0), 1.0)
        if w == 0.0:
            continue
        order = np.argsort(pi)
        k = np.clip(np.searchsorted(pi[order], idx), 0, len(pi) - 1)
        hit = pi[order][k] == idx                     # idx may repeat; pi are unique
        P[hit] += w * off[order][k[hit]]
    H = np.concatenate([P, np.ones((len(P), 1))], 1) @ eye.bind
    rest = H[:, :3]
    return eye.center + (rest - eye.center) @ np.asarray(rotation, np.float64).T


def iris_plane_distance(eye: EyeAsset, blend: dict) -> float:
    """Distance (mm) from the eye's rotation centre to the plane of its 8 iris landmarks, along the
    eye's optical axis (+ = in front of the centre), with the eyeball blend shapes ``blend``.

    The landmarks lie on the Inner mesh's planar front (model ``z = const``, perpendicular to the
    model's +Z, which the bind transform takes to the eye's forward), so this is their mean
    distance along that axis; the same at every eye rotation, which turns them about the centre."""
    P = inner_points(eye, blend, np.eye(3), eye.iris)
    n = eye.bind[2, :3] / np.linalg.norm(eye.bind[2, :3])
    return float(np.mean((P - eye.center) @ n))


def ring_radius(P) -> float:
    """Mean distance of points (k, d) from their centroid: the radius of a ring of landmarks."""
    P = np.asarray(P, float)
    return float(np.mean(np.linalg.norm(P - P.mean(0), axis=1)))


def eyelid_points(asset: RenderAsset, side: str, lid_weights: dict) -> np.ndarray:
    """(12, 3) posed eyelid landmarks of one eye (see the module docstring)."""
    eye = asset.eyes[side]
    if eye.lm_edge is not None and eye.lm_t is not None:
        E = eye.lm_edge
        P = posed_skin(asset, lid_weights, E.ravel()).reshape(N_EYELID, 2, 3)
        t = eye.lm_t[:, None]
        return (1.0 - t) * P[:, 0] + t * P[:, 1]
    pre = f"landmarks.{side}."
    pts = np.asarray(asset.rig_arrays[pre + "points"], np.float64)
    shapes = lids.shapes_from_arrays(asset.rig_arrays, prefix=pre)
    return lids.evaluate_shapes(pts, shapes, lid_weights)


def posed_landmarks(asset: RenderAsset, side: str, lid_weights: dict, blend: dict, rotation) -> np.ndarray:
    """(28, 3) head-frame landmarks of one eye: 12 eyelid, 8 iris, 8 pupil."""
    eye = asset.eyes[side]
    return np.concatenate([eyelid_points(asset, side, lid_weights),
                           inner_points(eye, blend, rotation, eye.iris),
                           inner_points(eye, blend, rotation, eye.pupil)])


def posed_lid_polygon(asset: RenderAsset, side: str, lid_weights: dict) -> np.ndarray:
    """(L, 3) the posed lid loop of one eye (the 12 eyelid landmarks without a stored loop)."""
    eye = asset.eyes[side]
    if eye.loop is None:
        return eyelid_points(asset, side, lid_weights)
    return posed_skin(asset, lid_weights, eye.loop)


def pupil_center(asset: RenderAsset, side: str, blend: dict, rotation) -> np.ndarray:
    """(3,) posed pupil centre (front pole of the Inner mesh), head mm."""
    eye = asset.eyes[side]
    return inner_points(eye, blend, rotation, [eye.pupil_center])[0]
