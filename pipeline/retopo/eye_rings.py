"""Concentric edge flow around the eyelid loops of a remeshed eye region (``retopo.eye_rings``).

:func:`add_eye_rings` replaces the faces within about ``(rings + 1)`` ring spacings of each loop
by ``rings`` rings of loop-sized vertex rings marched out over the dense surface, joined by
quads, and a greedy loft of triangles out to the cut's border. An eye whose rings come out
folded, flipped or with an obtuse loft sliver gets fewer rings, down to none.
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry import mesh_checks as mc
from pipeline.geometry.flips import count_flipped, relax, repair_flips
from pipeline.geometry.meshtopo import has_halfedge


def _band_faces(V, F, loop, radius, locked):
    """Faces of an annulus around ``loop`` reaching about ``radius`` (edge-graph distance) out.

    Every face with a corner nearer than ``radius`` is taken; pockets the band encloses are
    filled and pinch vertices (more than two band/rest edges) grown over until the band is
    an annulus: its border is ``loop`` plus one simple closed loop. Returns the (m,) bool face
    mask, or None when no such band exists (it would touch a ``locked`` vertex).
    """
    d = edge_graph_distance(V, F, loop, 2.0 * radius)
    return close_annulus(V, F, (d[F] < radius).any(axis=1), locked)


def edge_graph(V, F):
    """Sparse (n, n) symmetric CSR matrix of the edge lengths of (V, F): the graph
    :func:`edge_graph_distance` walks, built once for the crop's several walks (the handle check
    and the band's region round each opening: 30-40 ms each on a 150k-face crop)."""
    from scipy.sparse import coo_matrix

    n = len(V)
    e = mc.edges_of(F)
    w = np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1)
    G = coo_matrix((w, (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    return G.maximum(G.T)


def edge_graph_distance(V, F, seeds, limit, graph=None):
    """(n,) shortest distance along the edges of (V, F) from the vertices ``seeds`` (inf past
    ``limit``); ``graph``: :func:`edge_graph` of (V, F) when already built."""
    from scipy.sparse.csgraph import dijkstra

    G = edge_graph(V, F) if graph is None else graph
    return dijkstra(G, indices=np.asarray(seeds), min_only=True, limit=limit)


def close_annulus(V, F, band, locked):
    """The face mask ``band`` (round one boundary loop) grown into an annulus: pockets it
    encloses filled, pinch vertices (more than two band/rest edges) grown over, until its border
    is that loop plus one simple closed loop. Returns the (m,) bool mask, or None when no such
    band exists (it would touch a ``locked`` vertex, or it is not one annulus)."""
    from pipeline.geometry.meshtopo import face_adjacency, face_components

    n, m = len(V), len(F)
    band = np.array(band, dtype=bool)
    pairs, pair_edges = face_adjacency(F, n)
    for _ in range(50):
        rest = ~band
        # pockets: rest components other than the largest join the band
        lab = face_components(m, pairs, rest)
        sizes = np.bincount(lab[rest], minlength=m)
        band |= rest & (lab != int(np.argmax(sizes)))
        # the band/rest interface must be a simple loop: grow over pinch vertices
        inter = band[pairs[:, 0]] != band[pairs[:, 1]]
        cnt = np.bincount(pair_edges[inter].ravel(), minlength=n)
        pinch = np.flatnonzero(cnt > 2)
        if len(pinch) == 0:
            break
        band |= np.isin(F, pinch).any(axis=1)
    else:
        return None
    if len(locked) and np.isin(F[band], locked).any():
        return None
    # annulus: one component, Euler characteristic 0, two border loops (the eye loop + B)
    Fb = F[band]
    if len(np.unique(face_components(m, pairs, band)[band])) != 1:
        return None
    nv = len(np.unique(Fb))
    # undirected edges counted as one integer key each (np.unique over rows sorts a structured view)
    e = np.sort(mc.edges_of(Fb), axis=1)
    ne = len(np.unique(e[:, 0] * (int(Fb.max()) + 1) + e[:, 1])) if len(Fb) else 0
    if nv - ne + len(Fb) != 0:
        return None
    try:
        if len(mc.boundary_loops(Fb)) != 2:
            return None
    except ValueError:
        return None
    return band


def _outward_directions(P, normals, inside, smooth=3):
    """Unit directions in the surface, across the closed loop ``P`` towards ``inside``.

    Parameters
    ----------
    P : (N, 3) loop points ; normals : (N, 3) surface normals there
    inside : (N, 3) a point on the side the directions must point to, per loop vertex
    smooth : int
        Rounds of neighbour averaging: a staircase loop's kinks would cross the offset rings.

    Returns
    -------
    (N, 3) float64
    """
    T = np.roll(P, -1, axis=0) - np.roll(P, 1, axis=0)
    O = np.cross(T, normals)
    if np.sum(np.einsum("ij,ij->i", O, inside - P)) < 0:
        O = -O
    O /= np.maximum(np.linalg.norm(O, axis=1, keepdims=True), 1e-300)
    for _ in range(smooth):
        O = 0.5 * O + 0.25 * (np.roll(O, 1, axis=0) + np.roll(O, -1, axis=0))
        O -= np.einsum("ij,ij->i", O, normals)[:, None] * normals
        O /= np.maximum(np.linalg.norm(O, axis=1, keepdims=True), 1e-300)
    return O


def _march_rings(P, normals, inside, h, rings, ref_V, ref_F, smooth=1):
    """Rings of points marched out from the loop ``P`` in steps of ``h`` over the surface.

    Each step goes ``h`` across the current ring in the tangent plane and back onto the
    surface: short steps follow a surface that curls (the skin folding over an upper lid)
    where one long straight offset would land on the wrong side of the fold.

    Returns
    -------
    (rings, N, 3) float64
    """
    out = []
    Pk, Nk = P, normals
    for _ in range(rings):
        O = _outward_directions(Pk, Nk, inside)
        X = Pk + h * O
        # a little smoothing along the ring: where the loop has a notch the offsets converge
        # and would cross a few steps out
        for _ in range(smooth):
            X = 0.5 * X + 0.25 * (np.roll(X, 1, axis=0) + np.roll(X, -1, axis=0))
        _, fi, C = mc.closest_points(X, ref_V, ref_F)
        Nf = mc.face_normals(ref_V, np.asarray(ref_F)[fi])
        Nk = np.where(np.einsum("ij,ij->i", Nf, Nk)[:, None] < 0, -Nf, Nf)   # keep the side
        inside = C + O                                                       # keep going outward
        Pk = C
        out.append(C)
    return np.stack(out)


def _zip_strip(inner, outer, Vi, Vo, j0):
    """Greedy loft between two closed polylines: triangles (a, b, c) wound like the quads
    ``(inner[i], inner[i+1], outer[j+1], outer[j])``, each step closing the shorter diagonal."""
    N, M = len(inner), len(outer)
    i = j = 0
    tris = []
    while i < N or j < M:
        a, b = i % N, (i + 1) % N
        c, d = (j0 + j) % M, (j0 + j + 1) % M
        adv_inner = j >= M or (i < N and np.linalg.norm(Vi[b] - Vo[c]) <= np.linalg.norm(Vi[a] - Vo[d]))
        if adv_inner:
            tris.append((inner[a], inner[b], outer[c]))
            i += 1
        else:
            tris.append((inner[a], outer[d], outer[c]))
            j += 1
    return np.asarray(tris, dtype=np.int64)


def add_eye_rings(V, F, loops, ref_V, ref_F, rings=3, spacing=0.0, relax_iterations=4):
    """Concentric rings of quads around each eyelid loop.

    The faces within a band of ``(rings + 1) * spacing`` (edge-graph distance) around the loop
    are replaced by ``rings`` rings of ``N = len(loop)`` vertices (ring k marched out from the
    loop in ``k`` steps of ``spacing`` over the reference surface, :func:`_march_rings`), ``N``
    quads between consecutive rings (the loop is ring 0) and a loft of triangles from the
    outermost ring to the band's outer border B (:func:`_zip_strip`). An eye whose band cannot
    be made an annulus, or whose rings come out folded, flipped or with an obtuse loft sliver,
    is retried with fewer rings and keeps its old faces at none.

    Parameters
    ----------
    V : (n, 3) float64 ; F : (m, 3) int64
        Low-poly mesh, edge-manifold; eye loops are boundary loops.
    loops : dict side -> (N,) int64
        Ordered loop vertex indices (unchanged in the output, up to renumbering).
    ref_V : (r, 3) float64 ; ref_F : (s, 3) int64
        Dense surface the new vertices are projected onto (orientation reference too).
    rings : int
        New vertex rings per eye (= quad rings); 0 returns the input.
    spacing : float
        Ring spacing in mm; <= 0 uses the loop's mean edge length (square quads at the loop).
    relax_iterations : int

    Returns
    -------
    V2 : (n2, 3) float64
    F2 : (t, 3) int64
        Triangles other than the ring quads.
    Q : (q, 4) int64
        Ring quads, wound like ``F2``.
    loops2 : dict side -> (N,) int64
    info : dict side -> {"rings", "quads", "loft_triangles", "outer_vertices"} or {"skipped": why}
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    loops = {k: np.asarray(v, dtype=np.int64) for k, v in loops.items()}
    Q_all = np.zeros((0, 4), dtype=np.int64)
    info = {}
    if rings <= 0:
        return V, F, Q_all, loops, info
    flips0 = count_flipped(V, F, ref_V, ref_F)
    for side in list(loops):
        lp = loops[side]
        P = V[lp]
        h = float(spacing) if spacing > 0 else float(np.mean(np.linalg.norm(P - np.roll(P, -1, axis=0), axis=1)))
        # fewer rings where the full count folds (skin creasing close over a lid): the rings
        # stay where the surface allows them
        why = "band around the loop is not an annulus"
        for nr in range(int(rings), 0, -1):
            out = _ring_one_eye(V, F, Q_all, lp, ref_V, ref_F, nr, h, relax_iterations, flips0)
            if isinstance(out, str):
                why = out
                continue
            V, F, Q_all, remap, stats = out
            loops = {k: remap[v] for k, v in loops.items()}
            info[side] = stats
            break
        else:
            info[side] = {"rings": 0, "skipped": why}
    return V, F, Q_all, loops, info


def _ring_one_eye(V, F, Q_all, lp, ref_V, ref_F, rings, h, relax_iterations, flips0,
                  max_angle_deg=160.0):
    """One eye of ``add_eye_rings``: (V, F, Q_all, remap, stats), or why it failed (str)."""
    N = len(lp)
    # the quads of an eye done before are part of the surface but never of a band
    Fw = np.concatenate([F, Q_all[:, [0, 1, 2]], Q_all[:, [0, 2, 3]]])
    others = [np.asarray(b) for b in mc.boundary_loops(Fw) if not set(map(int, b)) & set(map(int, lp))]
    locked = np.unique(np.concatenate(others + [Q_all.ravel()]))
    band = _band_faces(V, Fw, lp, (rings + 1) * h, locked)
    if band is None:
        return "band around the loop is not an annulus"
    band = band[:len(F)]
    Fb, Fk = F[band], F[~band]
    # loop direction of the faces at the loop: the quads must keep it
    Lh = lp if has_halfedge(Fb, lp[0], lp[1]) else lp[::-1]
    lp_set = set(map(int, lp))
    B = next(b for b in mc.boundary_loops(Fb) if not set(map(int, b)) & lp_set)
    B = B[::-1]                     # the rest's faces run along B the way the band's run along the loop
    # new ring vertices marched out across the loop over the surface (offsets of a convex
    # opening diverge, so rings neither cross nor pinch at the canthi)
    Pl = V[Lh]
    Nl = mc.vertex_normals(V, Fb)[Lh]
    inside = np.zeros_like(Pl)
    for k, v in enumerate(Lh):                    # centroid of the band faces at the vertex
        inside[k] = V[Fb[(Fb == v).any(axis=1)]].mean(axis=(0, 1))
    C = _march_rings(Pl, Nl, inside, h, rings, ref_V, ref_F).reshape(-1, 3)
    j0 = int(np.argmin(np.linalg.norm(V[B] - C[-N], axis=1)))
    base = len(V)
    V2 = np.concatenate([V, C])
    R = np.vstack([Lh[None], base + np.arange(rings * N).reshape(rings, N)])     # (rings + 1, N)
    nxt = np.roll(np.arange(N), -1)
    quads = np.concatenate([np.stack([R[k], R[k][nxt], R[k + 1][nxt], R[k + 1]], axis=1)
                            for k in range(rings)])
    loft = _zip_strip(R[-1], B, V2[R[-1]], V2[B], j0)
    # drop the band's inner vertices (not on the loop or B), renumber
    Ftri = np.concatenate([Fk, loft])
    Qnew = np.concatenate([Q_all, quads])
    Fall = np.concatenate([Ftri, Qnew[:, [0, 1, 2]], Qnew[:, [0, 2, 3]]])
    used = np.unique(np.concatenate([Fall.ravel(), lp]))
    remap = -np.ones(len(V2), dtype=np.int64)
    remap[used] = np.arange(len(used))
    Vt, Fall_t = V2[used], remap[Fall]
    # B is the jagged edge of a face cut: relaxing it keeps the loft's triangles from
    # folding over its notches. The rings are not relaxed (a Laplacian shortens them,
    # pinching them onto the loop at the canthi), only repaired where a face came out flipped
    fixed = np.setdiff1d(np.arange(len(Vt)), remap[B])
    Vt = relax(Vt, Fall_t, fixed, ref_V, ref_F, iterations=max(relax_iterations, 8))
    if count_flipped(Vt, Fall_t, ref_V, ref_F) > flips0:
        fixed = np.setdiff1d(fixed, remap[R[1:].ravel()])
        Vt = repair_flips(Vt, Fall_t, fixed, ref_V, ref_F)
    rep = mc.check_mesh(Vt, Fall_t)
    flips = count_flipped(Vt, Fall_t, ref_V, ref_F)
    # an obtuse sliver in the loft (a B vertex on the outer ring's edge) folds as soon as the
    # lids move: no fewer rings would make one, so it counts as a failure
    new_faces = np.concatenate([remap[loft], remap[quads][:, [0, 1, 2]], remap[quads][:, [0, 2, 3]]])
    max_angle = float(mc.triangle_angles_deg(Vt, new_faces).max())
    if not rep.manifold or rep.degenerate_faces or flips > flips0 or max_angle > max_angle_deg:
        return (f"{rings} rings: manifold {rep.manifold}, {rep.degenerate_faces} degenerate, "
                f"{flips - flips0} flipped faces, largest angle {max_angle:.0f} deg")
    stats = {"rings": int(rings), "spacing_mm": round(h, 4), "quads": int(len(quads)),
             "loft_triangles": int(len(loft)), "outer_vertices": int(len(B))}
    return Vt, remap[Ftri], remap[Qnew], remap, stats
