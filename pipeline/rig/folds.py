"""Folds in the lid shapes: faces that turn over somewhere in the pitch sweep, and smoothing the
skin's motion around them (:func:`relax_folds`, called by the rig's build before its sweep).

The lid field (:mod:`pipeline.rig.lid_shapes`) is smooth in space; a fold comes from a sliver the
retopology left, where a smooth motion still carries one corner across the opposite edge.
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry.meshtopo import vertex_adjacency
from pipeline.rig.lids import BlendShape, evaluate_shapes, lid_weights


def flipped_faces(V, F, shapes, pitches_deg, max_pitch_deg: float) -> np.ndarray:
    """Faces (indices) whose normal turns by more than 90 degrees at any of ``pitches_deg``."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n0 = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    ok = np.linalg.norm(n0, axis=1) > 1e-12
    bad = np.zeros(len(F), bool)
    for p in pitches_deg:
        P = evaluate_shapes(V, shapes, lid_weights(p, max_pitch_deg))
        n1 = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
        bad |= ok & (np.einsum("ij,ij->i", n0, n1) <= 0)
    return np.flatnonzero(bad)


def relax_folds(V, F, shapes, eyes, pitches_deg, max_pitch_deg: float, rounds: int = 6,
                iterations: int = 8):
    """Smooth the shapes' motion of the skin around faces that turn over, until none does.

    The lid field is smooth in space, but on a sliver a smooth motion can still carry one corner
    across the opposite edge (a vertex lying almost on the edge of two others). Each round finds
    the faces that flip at any of ``pitches_deg``, takes their vertices and ``round`` rings of
    neighbours, less every margin and corner-strip vertex (their motion is the lid's), and
    replaces the displacement of those vertices in every stored pose by the mean of their
    neighbours' (``iterations`` Jacobi sweeps): locally the motion becomes nearly affine, which
    folds nothing. The round with the fewest flipped faces is returned (the shapes unchanged
    when none flips or no round helps).

    Returns
    -------
    shapes : list of BlendShape
    rounds_used : int
        The round returned; 0 = the shapes as given.
    n_relaxed : int
        Vertices whose motion was smoothed (all rounds).
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n = len(V)
    locked = np.zeros(n, bool)
    for e in eyes:
        locked[e.loop] = True
        locked[e.strip_inner] = True
    A = vertex_adjacency(F, n)
    deg = np.maximum(np.asarray(A.sum(axis=1)).ravel(), 1.0)
    touched = np.zeros(n, bool)
    bad = flipped_faces(V, F, shapes, pitches_deg, max_pitch_deg)
    best = (len(bad), shapes, 0, 0)
    for r in range(1, rounds + 1):
        if len(bad) == 0:
            break
        region = np.zeros(n, bool)
        region[F[bad].ravel()] = True
        for _ in range(r):
            region |= (A @ region.astype(np.float64)) > 0
        region &= ~locked
        touched |= region
        out = []
        for s in shapes:
            w, offs = s.knots()
            D = np.zeros((len(w) - 1, n, 3))
            D[:, s.point_indices] = offs[1:]
            for _ in range(iterations):
                for k in range(len(D)):
                    D[k, region] = (A @ D[k])[region] / deg[region, None]
            moved = np.flatnonzero(np.abs(D).max(axis=(0, 2)) > 0.0)
            out.append(BlendShape(name=s.name, point_indices=moved.astype(np.int64),
                                  offsets=D[-1, moved], inbetween_weights=s.inbetween_weights,
                                  inbetween_offsets=D[:-1][:, moved]))
        shapes = out
        bad = flipped_faces(V, F, shapes, pitches_deg, max_pitch_deg)
        if len(bad) < best[0]:
            best = (len(bad), shapes, r, int(touched.sum()))
    # smoothing next to a margin can also turn a face over: keep the round with the fewest folds
    return best[1], best[2], best[3]


def fold_sites(V, F, faces, mesh, eyes, limit: int = 3) -> list[str]:
    """Where the faces ``faces`` (indices into F) lie, for a refusal message: per face, its eye,
    its place in that eye's band (``band_<side>`` of the mesh, (R + 1, S) vertex ids, when the
    retopology built one: the face's ring and spoke, the lowest ring among its band corners; a
    face of the zip or the remesh is named by the band spoke nearest it) and its centroid in mm.
    At most ``limit`` faces, nearest the eyes first (a fold by the loop is the one that shows).

    Returns
    -------
    list of str, e.g. ``"left eye ring 2 spoke 45 at (32.3, 33.3, 96.8) mm"``
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) == 0 or not eyes:
        return []
    C = V[F[faces]].mean(axis=1)
    # nearest eye (distance to its loop's vertices) and that distance
    d = np.stack([np.linalg.norm(C[:, None] - V[e.loop][None], axis=2).min(axis=1) for e in eyes])
    which, dist = d.argmin(axis=0), d.min(axis=0)
    out = []
    for k in np.argsort(dist, kind="stable")[:limit]:
        e = eyes[int(which[k])]
        where = f"{e.side} eye"
        band = mesh.get(f"band_{e.side}") if hasattr(mesh, "get") else None
        if band is not None and np.size(band):
            band = np.asarray(band, dtype=np.int64)
            pos = {int(v): (r, s) for (r, s), v in np.ndenumerate(band)}
            corners = [pos[int(v)] for v in F[faces[k]] if int(v) in pos]
            if corners:
                r, s = min(corners)
                where += f" ring {r} spoke {s}"
            else:                  # outside the band: its nearest spoke on the outer ring
                s = int(np.linalg.norm(V[band[-1]] - C[k], axis=1).argmin())
                where += f" outside the band by spoke {s}"
        else:
            where += f" {dist[k]:.1f} mm from the loop"
        out.append(where + " at (" + ", ".join(f"{x:.1f}" for x in C[k]) + ") mm")
    return out
