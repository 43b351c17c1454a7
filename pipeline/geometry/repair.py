"""Safe mesh repairs and surface checks (vectorised; no per-face Python loops).

Only repairs that cannot change the shape are made: merging coincident
vertices, dropping zero-area and repeated faces, dropping small disconnected
components far from the eyes ("debris"), and dropping vertices no face uses.
:func:`repair_mesh` reports exactly what it removed and refuses (ScanError) when
the input is mostly degenerate or when the repairs would remove more than a
small share of the faces around an eye.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.errors import ScanError


@dataclass(frozen=True)
class RepairSettings:
    """Thresholds for :func:`repair_mesh` (the stage fills them from ``params.yaml``).

    Attributes
    ----------
    merge_tolerance_mm : float
        Vertices on the same grid cell of this size are merged (exact duplicates for tiny values).
    degenerate_area_mm2 : float
        Faces with area below this are degenerate.
    max_degenerate_fraction : float
        Refuse when more than this share of faces is degenerate.
    debris_max_fraction : float
        A component with fewer faces than this share of the mesh (and not the largest) is debris ...
    eye_radius_mm : float
        ... unless it comes within this distance of an eye hint; this is also the eye-region radius.
    max_eye_region_removed_fraction : float
        Refuse when repairs remove more than this share of the faces within ``eye_radius_mm`` of a hint.
    """

    merge_tolerance_mm: float = 1e-4
    degenerate_area_mm2: float = 1e-10
    max_degenerate_fraction: float = 0.1
    debris_max_fraction: float = 0.01
    eye_radius_mm: float = 20.0
    max_eye_region_removed_fraction: float = 0.05


@dataclass
class RepairResult:
    """Output of :func:`repair_mesh`.

    Attributes
    ----------
    V : (n', 3) float64
    F : (m', 3) int64
    vertex_index : (n',) int64
        Index of each output vertex in the input ``V``.
    face_index : (m',) int64
        Index of each output face in the input ``F``.
    counts : dict
        What was removed: merged_vertices, degenerate_faces, duplicate_faces, debris_components,
        debris_faces, unreferenced_vertices, small_components_kept_near_eyes.
    eye_region : dict
        Per eye: faces within the radius and how many repairs removed.
    """

    V: np.ndarray
    F: np.ndarray
    vertex_index: np.ndarray
    face_index: np.ndarray
    counts: dict = field(default_factory=dict)
    eye_region: dict = field(default_factory=dict)


def merge_vertices(V, F, tolerance: float):
    """Merge vertices that round to the same grid cell of size ``tolerance``.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    tolerance : float

    Returns
    -------
    V2 : (n', 3) float64
        The first vertex of each group (input order kept).
    F2 : (m, 3) int64
    keep : (n',) int64
        Input index of each kept vertex.
    """
    q = np.round(V / tolerance).astype(np.int64) if tolerance > 0 else V
    q = np.ascontiguousarray(q)
    rows = q.view(np.dtype((np.void, q.dtype.itemsize * 3))).ravel()
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    # renumber groups in order of first appearance so the output keeps the input order
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    keep = first[order]
    return V[keep], rank[inverse.reshape(-1)][F], keep


def face_areas(V, F) -> np.ndarray:
    """Triangle areas, shape (m,)."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def duplicate_face_mask(F) -> np.ndarray:
    """True for every face whose vertex set repeats an earlier face (either orientation)."""
    s = np.sort(F, axis=1)
    s = np.ascontiguousarray(s)
    rows = s.view(np.dtype((np.void, s.dtype.itemsize * 3))).ravel()
    _, first = np.unique(rows, return_index=True)
    mask = np.ones(len(F), dtype=bool)
    mask[first] = False
    return mask


def face_components(F, n_vertices: int):
    """Connected components of faces sharing vertices.

    Returns
    -------
    n : int
    labels : (m,) int64
        Component of each face.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows = np.concatenate([F[:, 0], F[:, 1]])
    cols = np.concatenate([F[:, 1], F[:, 2]])
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n_vertices, n_vertices))
    n, vlabels = connected_components(graph, directed=False)
    return n, vlabels[F[:, 0]].astype(np.int64)


def point_surface_distance(V, F, p, radius_hint: float | None = None) -> float:
    """Distance from point ``p`` to the triangle surface ``(V, F)``.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    p : (3,) float64
    radius_hint : float, optional
        Unused by the result; faces are pre-selected by their bounding spheres so
        only triangles that can be the closest are tested exactly.

    Returns
    -------
    float
    """
    from trimesh.triangles import closest_point

    p = np.asarray(p, dtype=np.float64)
    tri = V[F]
    centre = tri.mean(axis=1)
    rad = np.linalg.norm(tri - centre[:, None, :], axis=2).max(axis=1)
    dc = np.linalg.norm(centre - p, axis=1)
    upper = float((dc + rad).min())  # every point of that triangle is within this
    cand = np.flatnonzero(dc - rad <= upper)
    cp = closest_point(tri[cand], np.repeat(p[None], len(cand), axis=0))
    return float(np.linalg.norm(cp - p, axis=1).min())


def repair_mesh(V, F, hints: dict, settings: RepairSettings = RepairSettings(), path="mesh") -> RepairResult:
    """Make the safe repairs and report them.

    Parameters
    ----------
    V : (n, 3) float64
        Head-frame mm.
    F : (m, 3) int64
    hints : dict[str, (3,) float64]
        Eye hints, head-frame mm.
    settings : RepairSettings
    path : str or os.PathLike
        Named in errors.

    Returns
    -------
    RepairResult
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    m0, n0 = len(F), len(V)
    V1, F1, vkeep = merge_vertices(V, F, settings.merge_tolerance_mm)
    merged = n0 - len(V1)
    repeated = (F1[:, 0] == F1[:, 1]) | (F1[:, 1] == F1[:, 2]) | (F1[:, 0] == F1[:, 2])
    degenerate = repeated | (face_areas(V1, F1) < settings.degenerate_area_mm2)
    n_deg = int(degenerate.sum())
    if n_deg > settings.max_degenerate_fraction * m0:
        raise ScanError(path, f"{n_deg} of {m0} faces ({100.0 * n_deg / m0:.1f}%) are degenerate (zero area), "
                              f"over the limit of {100.0 * settings.max_degenerate_fraction:g}% (ingest.max_degenerate_fraction)")
    alive = ~degenerate
    dup = np.zeros(m0, dtype=bool)
    idx = np.flatnonzero(alive)
    dup[idx] = duplicate_face_mask(F1[idx])
    alive &= ~dup
    # debris: small components far from both eyes
    idx = np.flatnonzero(alive)
    if len(idx) == 0:
        raise ScanError(path, "no faces left after removing degenerate and duplicate faces")
    n_comp, labels = face_components(F1[idx], len(V1))
    sizes = np.bincount(labels, minlength=n_comp)
    small = (sizes < settings.debris_max_fraction * len(idx)) & (np.arange(n_comp) != np.argmax(sizes))
    near = np.zeros(n_comp, dtype=bool)
    for h in hints.values():
        dv = np.linalg.norm(V1 - np.asarray(h, float), axis=1) <= settings.eye_radius_mm
        face_near = dv[F1[idx]].any(axis=1)
        near[np.unique(labels[face_near])] = True
    debris_comp = small & ~near
    debris = np.zeros(m0, dtype=bool)
    debris[idx] = debris_comp[labels]
    alive &= ~debris
    # eye-region accounting (faces of the input, by centroid)
    removed = ~alive
    centroids = V[F].mean(axis=1)
    eye_region = {}
    for side, h in hints.items():
        inside = np.linalg.norm(centroids - np.asarray(h, float), axis=1) <= settings.eye_radius_mm
        total, lost = int(inside.sum()), int((inside & removed).sum())
        eye_region[side] = {"faces": total, "removed": lost}
        if total and lost > settings.max_eye_region_removed_fraction * total:
            raise ScanError(path, f"repairs would remove {lost} of the {total} faces ({100.0 * lost / total:.1f}%) "
                                  f"within {settings.eye_radius_mm:g} mm of the {side} eye hint, over the limit of "
                                  f"{100.0 * settings.max_eye_region_removed_fraction:g}%: the eye region is damaged")
    face_index = np.flatnonzero(alive)
    F2 = F1[face_index]
    used = np.zeros(len(V1), dtype=bool)
    used[F2.ravel()] = True
    remap = np.cumsum(used) - 1
    counts = {
        "merged_vertices": int(merged),
        "degenerate_faces": n_deg,
        "duplicate_faces": int(dup.sum()),
        "debris_components": int(debris_comp.sum()),
        "debris_faces": int(debris.sum()),
        "unreferenced_vertices": int(len(V1) - used.sum()),
        "small_components_kept_near_eyes": int((small & near).sum()),
        "components": int(n_comp - debris_comp.sum()),
    }
    return RepairResult(V=V1[used], F=remap[F2], vertex_index=vkeep[used], face_index=face_index,
                        counts=counts, eye_region=eye_region)


def mean_normal_near(V, F, p, radius: float) -> np.ndarray:
    """Area-weighted mean face normal (unnormalised) of faces with centroid within ``radius`` of ``p``."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    inside = np.linalg.norm((a + b + c) / 3.0 - p, axis=1) <= radius
    return 0.5 * np.cross(b[inside] - a[inside], c[inside] - a[inside]).sum(axis=0)
