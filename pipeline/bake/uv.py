"""UV unwrapping of the low-poly eye region and texel rasterisation (numpy).

Two unwraps: :func:`conformal_unwrap`, one least-squares conformal chart per half of the eye
region (the halves split between the two openings), packed side by side: milliseconds, and
seams only down the middle; and :func:`unwrap` (xatlas), seconds, for any mesh, the fallback
where a conformal chart is not one-to-one.
"""

from __future__ import annotations

import numpy as np


def unwrap(V, F, resolution=2048, padding=4, seed_options=None):
    """UV-unwrap a triangle mesh with xatlas.

    Parameters
    ----------
    V : (n, 3) float64, F : (m, 3) int64
    resolution : int
        Atlas resolution the charts are packed for (texels).
    padding : int
        Texels between charts.

    Returns
    -------
    UV : (k, 2) float64 in [0, 1], origin bottom-left
    FUV : (m, 3) int64 per-corner indices into UV, same face order as ``F``
    """
    import xatlas

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    atlas = xatlas.Atlas()
    atlas.add_mesh(V.astype(np.float32) - V.mean(axis=0).astype(np.float32), F.astype(np.uint32))
    co = xatlas.ChartOptions()
    po = xatlas.PackOptions()
    po.resolution = int(resolution)
    po.padding = int(padding)
    po.bilinear = True
    po.blockAlign = False
    atlas.generate(co, po)
    vmap, idx, uvs = atlas[0]
    idx = np.asarray(idx, dtype=np.int64)
    vmap = np.asarray(vmap, dtype=np.int64)
    if len(idx) != len(F) or not np.array_equal(vmap[idx], F):
        raise RuntimeError("xatlas changed the face order or topology")
    return np.asarray(uvs, dtype=np.float64), idx


class UnwrapError(ValueError):
    """A conformal chart that is not one-to-one (a flipped triangle, a boundary crossing itself)."""


def _chart_lscm(V, F):
    """Least-squares conformal map of one connected chart, scaled to millimetres (its UV area
    equals its surface area) and turned to its smallest bounding rectangle, corner at the origin.

    Raises
    ------
    UnwrapError
        When the chart has no boundary, a triangle flips, or its boundary crosses itself.
    """
    import igl

    from pipeline.geometry.meshtopo import boundary_halfedges

    H = boundary_halfedges(F)
    if len(H) == 0:
        raise UnwrapError("a closed chart has no boundary to open it at")
    # pins: the two boundary vertices farthest apart (a pair near each other leaves the scale ill-posed)
    b = np.unique(H)
    P = V[b]
    i = int(np.argmax(np.linalg.norm(P - P[0], axis=1)))
    j = int(np.argmax(np.linalg.norm(P - P[i], axis=1)))
    try:
        UV, _ = igl.lscm(V, F, np.array([b[i], b[j]]), np.array([[0.0, 0.0], [1.0, 0.0]]))
    except RuntimeError as exc:      # a singular system (a face of zero area): the atlas instead
        raise UnwrapError(f"the conformal map failed ({exc})") from None
    UV = np.asarray(UV, dtype=np.float64)
    e1, e2 = UV[F[:, 1]] - UV[F[:, 0]], UV[F[:, 2]] - UV[F[:, 0]]
    a2 = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    if not np.isfinite(UV).all() or not (np.all(a2 > 0) or np.all(a2 < 0)):
        raise UnwrapError(f"{int(min((a2 <= 0).sum(), (a2 >= 0).sum()))} triangles flip in the conformal map")
    if a2[0] < 0:                                    # mirrored: keep the faces' winding
        UV[:, 0] *= -1.0
    a3 = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    UV *= np.sqrt(a3.sum() / np.abs(a2).sum())
    _check_simple_boundary(UV, H)
    from scipy.spatial import ConvexHull

    hull = UV[ConvexHull(UV).vertices]
    best = None
    for e in np.diff(np.vstack([hull, hull[:1]]), axis=0):   # the smallest rectangle has a hull edge on a side
        c, s = e / np.linalg.norm(e)
        R = np.array([[c, s], [-s, c]])
        Q = hull @ R.T
        area = float(np.prod(Q.max(0) - Q.min(0)))
        if best is None or area < best[0]:
            best = (area, R)
    UV = UV @ best[1].T
    return UV - UV.min(axis=0)


def _check_simple_boundary(UV, H):
    """Raise :class:`UnwrapError` when two boundary edges of the chart ``UV`` cross (edges that
    share a vertex are not compared)."""
    A, B = UV[H[:, 0]], UV[H[:, 1]]
    lo, hi = np.minimum(A, B), np.maximum(A, B)
    for k in range(0, len(H), 256):                  # (256, k) blocks: memory stays small
        sl = slice(k, k + 256)
        near = np.all((lo[sl, None] <= hi[None]) & (lo[None] <= hi[sl, None]), axis=2)
        near &= ~((H[sl, None, 0] == H[None, :, 0]) | (H[sl, None, 0] == H[None, :, 1])
                  | (H[sl, None, 1] == H[None, :, 0]) | (H[sl, None, 1] == H[None, :, 1]))
        i, j = np.nonzero(near)
        i += k

        def orient(p, q, r):
            return np.sign((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0]))

        cross = ((orient(A[i], B[i], A[j]) * orient(A[i], B[i], B[j]) < 0)
                 & (orient(A[j], B[j], A[i]) * orient(A[j], B[j], B[i]) < 0))
        if cross.any():
            raise UnwrapError(f"{int(cross.sum()) // 2} boundary edges cross in the conformal map")


def conformal_unwrap(V, F, side, resolution=2048, padding=4):
    """One least-squares conformal chart per connected piece of each side, packed into [0, 1]^2.

    A conformal map keeps the texels square and, unlike xatlas' many charts, leaves seams only
    where ``side`` changes; both eye openings are free boundaries, so nothing around them is cut.

    Parameters
    ----------
    V : (n, 3) float64, F : (m, 3) int64
    side : (m,) int
        The chart group of each face (e.g. which side of the face's midline); a group's connected
        pieces are charts of their own.
    resolution : int
        Atlas texels per side; with ``padding``, the gap between charts and round the border.

    Returns
    -------
    UV : (k, 2) float64 in [0, 1], origin bottom-left
    FUV : (m, 3) int64 per-corner indices into UV, same face order as ``F``

    Raises
    ------
    UnwrapError
        When a chart is not one-to-one (use :func:`unwrap` then).
    """
    from pipeline.geometry.meshtopo import face_components_by_vertex

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    side = np.asarray(side)
    charts = []
    for g in np.unique(side):
        fg = np.nonzero(side == g)[0]
        _, lab = face_components_by_vertex(F[fg], len(V))
        for c in np.unique(lab):                  # (vertices outside the group are components too)
            faces = fg[lab == c]
            verts, local = np.unique(F[faces], return_inverse=True)
            charts.append((faces, verts, _chart_lscm(V[verts], local.reshape(-1, 3))))
    # shelf packing, tallest first: rows left to right; the scale is the largest that fits
    order = sorted(range(len(charts)), key=lambda k: -charts[k][2][:, 1].max())
    size = np.array([charts[k][2].max(axis=0) for k in order])          # (c, 2) mm
    gap = float(padding) / float(resolution)

    def place(scale):
        pos, x, y, row_h = [], gap, gap, 0.0
        for w, h in size * scale:
            if x + w + gap > 1.0 and x > gap:                          # next row
                x, y, row_h = gap, y + row_h + gap, 0.0
            pos.append((x, y))
            x, row_h = x + w + gap, max(row_h, h)
        fits = all(px + w + gap <= 1.0 + 1e-12 for (px, _), w in zip(pos, size[:, 0] * scale))
        return fits and y + row_h + gap <= 1.0 + 1e-12, pos

    lo, hi = 0.0, (1.0 - 2 * gap) / float(size.max())
    for _ in range(40):                                                # bisection on the scale
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if place(mid)[0] else (lo, mid)
    pos = place(lo)[1]
    UV, FUV, k0 = [], np.zeros_like(F), 0
    for (faces, verts, uv), p in zip((charts[k] for k in order), pos):
        UV.append(uv * lo + np.asarray(p))
        FUV[faces] = np.searchsorted(verts, F[faces]) + k0
        k0 += len(verts)
    return np.concatenate(UV), FUV


def rasterize(UV, FUV, width, height):
    """Texels whose centres fall inside each UV triangle.

    Image convention: texel (row j, column i) has its centre at
    ``u = (i + 0.5) / width``, ``v = 1 - (j + 0.5) / height``.

    Returns
    -------
    rows : (t,) int64, cols : (t,) int64
    face : (t,) int64 triangle of each texel
    bary : (t, 3) float64 barycentric coordinates of the texel centre in that triangle
    (a texel covered by two triangles keeps the first one).
    """
    UV = np.asarray(UV, dtype=np.float64)
    T = UV[np.asarray(FUV, dtype=np.int64)]                # (m, 3, 2)
    X = T[..., 0] * width - 0.5                            # texel-centre coordinates
    Y = (1.0 - T[..., 1]) * height - 0.5
    x0 = np.clip(np.ceil(X.min(axis=1)), 0, width - 1).astype(np.int64)
    x1 = np.clip(np.floor(X.max(axis=1)), -1, width - 1).astype(np.int64)
    y0 = np.clip(np.ceil(Y.min(axis=1)), 0, height - 1).astype(np.int64)
    y1 = np.clip(np.floor(Y.max(axis=1)), -1, height - 1).astype(np.int64)
    w = np.maximum(x1 - x0 + 1, 0)
    h = np.maximum(y1 - y0 + 1, 0)
    cnt = w * h
    rows_out, cols_out, face_out, bary_out = [], [], [], []
    total = int(cnt.sum())
    if total == 0:
        e = np.zeros(0, dtype=np.int64)
        return e, e, e, np.zeros((0, 3))
    # barycentric coordinates as affine functions of the texel centre: l_k = a_k x + b_k y + c_k
    ax, ay, bx, by, cx, cy = X[:, 0], Y[:, 0], X[:, 1], Y[:, 1], X[:, 2], Y[:, 2]
    det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
    ok = np.abs(det) > 1e-14
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    a0, b0 = (by - cy) * inv, (cx - bx) * inv
    c0 = -(a0 * cx + b0 * cy)
    a1, b1 = (cy - ay) * inv, (ax - cx) * inv
    c1 = -(a1 * cx + b1 * cy)
    # the candidates: per triangle and texel row, the columns where the row can be inside. Each
    # barycentric is affine in x along the row, and its half-line l >= eps bounds x from one side
    # (a texel of slack each way for rounding; a slope under 1e-9 per texel bounds nothing). The
    # triangles' bounding boxes held 4.5M candidates for the 2.1M texels of a 2048 atlas.
    eps = -1e-9
    hh = np.where(ok, h, 0)
    fr = np.repeat(np.arange(len(T)), hh)                              # (face, row) pairs
    yr = np.repeat(y0, hh) + (np.arange(len(fr)) - np.repeat(np.cumsum(hh) - hh, hh))
    lo, hi = x0[fr].astype(np.float64), x1[fr].astype(np.float64)
    a2, b2, c2 = -(a0 + a1), -(b0 + b1), 1.0 - c0 - c1                   # l2 = 1 - l0 - l1
    for a, b, c in ((a0, b0, c0), (a1, b1, c1), (a2, b2, c2)):
        A = a[fr]
        with np.errstate(divide="ignore", invalid="ignore"):
            edge = (eps - (b[fr] * yr + c[fr])) / A
        lo = np.where(A > 1e-9, np.maximum(lo, edge), lo)
        hi = np.where(A < -1e-9, np.minimum(hi, edge), hi)
    xs = np.maximum(np.ceil(lo) - 1, x0[fr]).astype(np.int64)
    xe = np.minimum(np.floor(hi) + 1, x1[fr]).astype(np.int64)
    n = np.maximum(xe - xs + 1, 0)
    if int(n.sum()) == 0:
        e = np.zeros(0, dtype=np.int64)
        return e, e, e, np.zeros((0, 3))
    starts = np.concatenate([[0], np.cumsum(n)])
    # in pieces of ~1M candidates to bound memory (temporaries stay small enough for the
    # allocator to reuse them; bigger chunks page-fault fresh memory every time); the candidates
    # come face by face, row by row, column by column, as the bounding boxes' did
    chunk = 1_000_000
    rows_out, cols_out, face_out, bary_out = [], [], [], []
    p_lo, n_pairs = 0, len(fr)
    while p_lo < n_pairs:
        p_hi = int(np.searchsorted(starts, starts[p_lo] + chunk, side="right")) - 1
        p_hi = min(max(p_hi, p_lo + 1), n_pairs)
        c = n[p_lo:p_hi]
        fid = np.repeat(fr[p_lo:p_hi], c)
        xi = np.repeat(xs[p_lo:p_hi] - (starts[p_lo:p_hi] - starts[p_lo]), c) + np.arange(int(c.sum()))
        yi = np.repeat(yr[p_lo:p_hi], c)
        l0 = a0[fid] * xi + b0[fid] * yi + c0[fid]
        l1 = a1[fid] * xi + b1[fid] * yi + c1[fid]
        l2 = 1.0 - l0 - l1
        inside = (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
        rows_out.append(yi[inside])
        cols_out.append(xi[inside])
        face_out.append(fid[inside])
        bary_out.append(np.stack([l0[inside], l1[inside], l2[inside]], axis=1))
        p_lo = p_hi
    rows = np.concatenate(rows_out)
    cols = np.concatenate(cols_out)
    face = np.concatenate(face_out)
    bary = np.clip(np.concatenate(bary_out), 0.0, 1.0)
    bary /= bary.sum(axis=1, keepdims=True)
    lin = rows * width + cols
    _, first = np.unique(lin, return_index=True)
    return rows[first], cols[first], face[first], bary[first]


def dilation_sources(mask, iterations):
    """Where :func:`dilate` pads past the edges of ``mask`` (H, W) bool, computed once for any
    number of images: ``grow`` (H, W) bool, the padded texels, and ``sy``, ``sx`` (k,), the row and
    column of the masked texel each of them copies (``img[grow] = img[sy, sx]``)."""
    from scipy import ndimage

    mask = np.asarray(mask, dtype=bool)
    if not mask.any() or iterations <= 0:
        none = np.zeros(0, dtype=np.int64)
        return np.zeros_like(mask), none, none
    # the transform runs on the mask's bounding box grown by the padding (the atlas leaves a
    # third of a 2048 map's columns empty): texels farther out are never padded, and texels
    # outside the mask hold no feature, so every row's and column's candidates, and so the
    # nearest texel chosen (ties included), are those of the whole image
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    r0, r1 = max(rows[0] - iterations - 1, 0), min(rows[-1] + iterations + 2, mask.shape[0])
    c0, c1 = max(cols[0] - iterations - 1, 0), min(cols[-1] + iterations + 2, mask.shape[1])
    box = mask[r0:r1, c0:c1]
    dist, (iy, ix) = ndimage.distance_transform_edt(~box, return_indices=True)
    grow_box = (~box) & (dist <= iterations)
    grow = np.zeros_like(mask)
    grow[r0:r1, c0:c1] = grow_box
    return grow, iy[grow_box] + r0, ix[grow_box] + c0


def dilate(img, mask, iterations):
    """Pad ``img`` past the edges of ``mask``: texels within ``iterations`` texels of the mask
    take the value of the nearest masked texel (Euclidean distance transform).

    Parameters
    ----------
    img : (H, W) or (H, W, C) array
    mask : (H, W) bool, True where ``img`` holds baked values

    Returns
    -------
    img, mask : the padded image (same dtype) and the grown mask (inputs are not modified)
    """
    mask = np.asarray(mask, dtype=bool)
    img = np.array(img, copy=True)
    grow, sy, sx = dilation_sources(mask, iterations)
    img[grow] = img[sy, sx]
    return img, mask | grow


def sample_bilinear(img, uv):
    """Bilinear lookup of an image at UVs (origin bottom-left; clamped at the borders).

    Parameters
    ----------
    img : (H, W) or (H, W, C) array
    uv : (k, 2) float

    Returns
    -------
    (k,) or (k, C) float64
    """
    img = np.asarray(img)
    H, W = img.shape[:2]
    x = np.asarray(uv)[:, 0] * W - 0.5
    y = (1.0 - np.asarray(uv)[:, 1]) * H - 0.5
    x = np.clip(x, 0, W - 1)
    y = np.clip(y, 0, H - 1)
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    x1 = np.minimum(x0 + 1, W - 1)
    y1 = np.minimum(y0 + 1, H - 1)
    fx = x - x0
    fy = y - y0
    if img.ndim == 3:
        fx = fx[:, None]
        fy = fy[:, None]
    flat = img.reshape((H * W,) + img.shape[2:])   # 1-D gathers: same values, faster than 2-D indexing
    r0, r1 = y0 * W, y1 * W
    a = flat.take(r0 + x0, axis=0).astype(np.float64)
    b = flat.take(r0 + x1, axis=0).astype(np.float64)
    c = flat.take(r1 + x0, axis=0).astype(np.float64)
    d = flat.take(r1 + x1, axis=0).astype(np.float64)
    return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy
