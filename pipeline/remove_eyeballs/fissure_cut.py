"""Cutting an eye opening along the fissure a texture shows (coarse textured scans).

A coarse scan's faces (``james``: ~3 mm) are far larger than the detail of the opening, so a cut
along its edges cannot follow the fissure. :func:`refine_along` splits the faces around each
outline until their median edge is at most ``edge_mm`` long (edge midpoints, so the surface and its
texture mapping do not change; a face with one, two or three split edges becomes two, three or
four, so the mesh stays conforming); :func:`region_inside` then selects the faces seen inside an
outline, and :func:`move_loop_onto` puts the cut's boundary loop on the outline itself.
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry.flips import move_guarded
from pipeline.placement.fissure import points_in_polygon


def _outline_distance(Q, poly):
    """(k,) distance of plane points (k, 2) to a closed polyline (p, 2)."""
    A = np.asarray(poly, float)
    B = np.roll(A, -1, axis=0)
    AB = B - A
    L2 = np.maximum((AB * AB).sum(axis=1), 1e-300)
    out = np.full(len(Q), np.inf)
    for start in range(0, len(Q), 4096):
        q = Q[start:start + 4096]
        t = np.clip(np.einsum("kpd,pd->kp", q[:, None, :] - A[None], AB) / L2, 0.0, 1.0)
        C = A[None] + t[..., None] * AB[None]
        out[start:start + 4096] = np.linalg.norm(C - q[:, None, :], axis=2).min(axis=1)
    return out


def _split_edges(arrays: dict, marked: set) -> tuple[dict, np.ndarray]:
    """Split the ``marked`` undirected edges ``(a, b)`` (a < b) at their midpoints.

    Returns the new arrays (``V``, ``F`` and, when present, ``UV``/``FUV``, ``VC``, any other
    per-face array copied to the children) and ``parent`` (new face -> old face).
    """
    V = np.asarray(arrays["V"], np.float64)
    F = np.asarray(arrays["F"], np.int64)
    has_uv = "UV" in arrays and "FUV" in arrays
    UV = np.asarray(arrays["UV"], np.float64) if has_uv else None
    FUV = np.asarray(arrays["FUV"], np.int64) if has_uv else None
    mid = {}
    newV = []
    for a, b in sorted(marked):
        mid[(a, b)] = len(V) + len(newV)
        newV.append(0.5 * (V[a] + V[b]))
    uv_mid = {}
    newUV = []

    def uvm(ta, tb):
        key = (min(ta, tb), max(ta, tb))
        if key not in uv_mid:
            uv_mid[key] = len(UV) + len(newUV)
            newUV.append(0.5 * (UV[ta] + UV[tb]))
        return uv_mid[key]

    outF, outT, parent = [], [], []
    for fi, f in enumerate(F.tolist()):
        t = FUV[fi].tolist() if has_uv else [0, 0, 0]
        m = [mid.get((min(f[i], f[(i + 1) % 3]), max(f[i], f[(i + 1) % 3]))) for i in range(3)]
        k = sum(x is not None for x in m)
        if k == 0:
            outF.append(f)
            outT.append(t)
            parent.append(fi)
            continue
        mt = [uvm(t[i], t[(i + 1) % 3]) if (m[i] is not None and has_uv) else None for i in range(3)]
        # rotate so that the pattern starts at a split edge; corners v0 v1 v2, edge i = (vi, vi+1)
        r = next(i for i in range(3) if m[i] is not None) if k < 3 else 0
        if k == 2:
            r = next(i for i in range(3) if m[i] is not None and m[(i + 1) % 3] is not None)
        v = [f[(r + i) % 3] for i in range(3)]
        tv = [t[(r + i) % 3] for i in range(3)]
        e = [m[(r + i) % 3] for i in range(3)]
        te = [mt[(r + i) % 3] for i in range(3)]
        if k == 1:
            tris = [((v[0], e[0], v[2]), (tv[0], te[0], tv[2])), ((e[0], v[1], v[2]), (te[0], tv[1], tv[2]))]
        elif k == 2:                     # edges 0 and 1 split
            tris = [((e[0], v[1], e[1]), (te[0], tv[1], te[1])), ((v[0], e[0], e[1]), (tv[0], te[0], te[1])),
                    ((v[0], e[1], v[2]), (tv[0], te[1], tv[2]))]
        else:
            tris = [((v[0], e[0], e[2]), (tv[0], te[0], te[2])), ((e[0], v[1], e[1]), (te[0], tv[1], te[1])),
                    ((e[2], e[1], v[2]), (te[2], te[1], tv[2])), ((e[0], e[1], e[2]), (te[0], te[1], te[2]))]
        for tri, tt in tris:
            outF.append(list(tri))
            outT.append(list(tt))
            parent.append(fi)
    parent = np.asarray(parent, np.int64)
    out = {}
    nV, nF = len(V), len(F)
    edges = sorted(marked, key=lambda ab: mid[ab])
    ea = np.array([a for a, _ in edges], np.int64)
    eb = np.array([b for _, b in edges], np.int64)
    for k, a in arrays.items():
        a = np.asarray(a)
        if k == "V":
            out[k] = np.concatenate([V, np.asarray(newV).reshape(-1, 3)])
        elif k == "F":
            out[k] = np.asarray(outF, np.int64)
        elif k == "UV" and has_uv:
            out[k] = np.concatenate([UV, np.asarray(newUV).reshape(-1, 2)])
        elif k == "FUV" and has_uv:
            out[k] = np.asarray(outT, np.int64)
        elif k in ("poly_counts", "poly_indices"):
            continue                     # polygons do not survive a split of their triangles
        elif a.ndim >= 1 and a.shape[0] == nV and k != "UV":
            mixed = 0.5 * (a[ea].astype(np.float64) + a[eb].astype(np.float64))
            out[k] = np.concatenate([a, np.round(mixed).astype(a.dtype) if a.dtype.kind in "iu" else mixed])
        elif a.ndim >= 1 and a.shape[0] == nF and k not in ("FUV",):
            out[k] = a[parent]
        else:
            out[k] = a
    return out, parent


def refine_along(arrays: dict, outlines: list, edge_mm: float = 0.8, radius_mm: float = 40.0,
                 max_levels: int = 3) -> tuple[dict, np.ndarray]:
    """Split the faces around each outline until their median edge is at most ``edge_mm``.

    Every face within ``radius_mm`` of a fissure's hint is split 1-to-4 at each level (the
    median edge there decides how many levels, at most ``max_levels``): a uniform split keeps
    the faces' shapes, and the faces it borders get one or two edges split only out there,
    beyond the eye region that retopo keeps (faces with three collinear corners along a split
    edge would come back from its decimation as zero-area faces, and their removal as holes).

    Parameters
    ----------
    arrays : dict
        Mesh arrays (``V``, ``F``, optional ``UV``/``FUV``, ``VC``, per-face arrays).
    outlines : list of dict
        ``outline_2d`` (p, 2), ``hint`` (3,), ``basis`` (2, 3) of each fissure
        (:class:`pipeline.placement.texture.TextureEyeFit`).

    Returns
    -------
    arrays : dict
    parent : (m', ) int64
        Face of the input mesh each output face lies in.
    """
    V = np.asarray(arrays["V"], np.float64)
    F = np.asarray(arrays["F"], np.int64)
    c = V[F].mean(axis=1)
    near = np.zeros(len(F), bool)
    for o in outlines:
        near |= np.linalg.norm(c - o["hint"], axis=1) < radius_mm
    out = dict(arrays)
    parent = np.arange(len(F), dtype=np.int64)
    if not near.any():
        return out, parent
    T = V[F[near]]
    edge = float(np.median(np.linalg.norm(T - np.roll(T, 1, axis=1), axis=2)))
    levels = int(min(max_levels, max(0, np.ceil(np.log2(edge / edge_mm)))))
    sel = near
    for _ in range(levels):
        Fn = np.asarray(out["F"], np.int64)[sel]
        ed = np.sort(np.concatenate([Fn[:, [0, 1]], Fn[:, [1, 2]], Fn[:, [2, 0]]]), axis=1)
        out, p = _split_edges(out, set(map(tuple, ed.tolist())))
        parent = parent[p]
        # the children of the faces split 1-to-4 (four per face) are the next level's faces
        counts = np.bincount(p, minlength=len(sel))
        sel = (sel & (counts == 4))[p]
    return out, parent


def region_inside(V, F, fissure: dict) -> np.ndarray:
    """(m,) bool: faces turned toward the fissure's viewing direction whose centre, seen along it,
    lies inside its outline (within 25 mm of its hint)."""
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    c = V[F].mean(axis=1)
    view = np.asarray(fissure["view"], np.float64)
    N = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    cand = np.flatnonzero((np.linalg.norm(c - fissure["hint"], axis=1) < 25.0) & ((N @ view) > 0))
    out = np.zeros(len(F), bool)
    q = (c[cand] - fissure["hint"]) @ np.asarray(fissure["basis"]).T
    out[cand[points_in_polygon(q, fissure["outline_2d"])]] = True
    return out


def move_loop_onto(V, F, loop, fissure: dict, min_cos: float = 0.5) -> float:
    """Move the cut's loop vertices (``V`` in place) onto the fissure's outline: each to the
    outline point nearest it seen along the viewing direction (its 3D point interpolated along
    the lifted outline), the loop vertex nearest each canthus onto that canthus. A move that
    would turn a face next to it by more than ``acos(min_cos)`` is halved, up to three times,
    then dropped. Returns the mean move, mm."""
    V3 = np.asarray(fissure["outline"], np.float64)
    Q2 = np.asarray(fissure["outline_2d"], np.float64)
    hint, B = fissure["hint"], np.asarray(fissure["basis"])
    q = (V[loop] - hint) @ B.T
    A, Bq = Q2, np.roll(Q2, -1, axis=0)
    AB = Bq - A
    L2 = np.maximum((AB * AB).sum(axis=1), 1e-300)
    t = np.clip(np.einsum("kpd,pd->kp", q[:, None, :] - A[None], AB) / L2, 0.0, 1.0)
    C = A[None] + t[..., None] * AB[None]
    j = np.argmin(np.linalg.norm(C - q[:, None, :], axis=2), axis=1)
    tk = t[np.arange(len(loop)), j]
    target = (1.0 - tk)[:, None] * V3[j] + tk[:, None] * np.roll(V3, -1, axis=0)[j]
    for corner in (0, int(fissure["lateral"])):
        i = int(np.argmin(np.linalg.norm(q - Q2[corner], axis=1)))
        target[i] = V3[corner]
    return move_guarded(V, F, loop, target, min_cos, min_area_ratio=0.05)


def openings_at_fissures(arrays: dict, fits: dict, edge_mm: float = 0.8):
    """The mesh refined along the fissure of every texture-placed eye (``fit.fissure``), and each
    eye's removal region on it: the faces inside its outline (one piece, no islands: the region
    cleaning of :mod:`pipeline.placement.eye_fit`), or for an eye placed from geometry its region
    carried to the refined faces. Returns ``(arrays, fits)``; without a fissure, the input."""
    from pipeline.placement.eye_fit import EyeMesh, clean_region

    outlines = [f.fissure for f in fits.values() if getattr(f, "fissure", None) is not None]
    if not outlines:
        return arrays, fits
    out, parent = refine_along(arrays, outlines, edge_mm=edge_mm)
    V, F = np.asarray(out["V"], np.float64), np.asarray(out["F"], np.int64)
    mesh = None
    for fit in fits.values():
        fis = getattr(fit, "fissure", None)
        if fis is None:
            fit.region = np.asarray(fit.region)[parent]
            continue
        mesh = mesh or EyeMesh(V, F)
        inside = region_inside(V, F, fis)
        near = np.linalg.norm(mesh.centroids - fis["hint"], axis=1) < 30.0
        fit.region = clean_region(mesh, inside, inside, near)
    return out, fits
