"""Batched ray casting against the dense scan with Embree (embreex), float32-safe."""

from __future__ import annotations

import os

import numpy as np


class DenseScene:
    """An Embree scene of a dense triangle mesh, re-centred before the float32 conversion.

    Parameters
    ----------
    V : (n, 3) float64, F : (m, 3) int64
    face_ids : optional (m,) int64, kept as ``face_ids``: where each face of ``F`` comes from
        (e.g. its index in the whole scan when ``F`` is a part of it)
    """

    def __init__(self, V, F, face_ids=None):
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh

        self.V = np.asarray(V, dtype=np.float64)
        self.F = np.asarray(F, dtype=np.int64)
        self.face_ids = None if face_ids is None else np.asarray(face_ids, dtype=np.int64)
        self.origin = 0.5 * (self.V.min(axis=0) + self.V.max(axis=0))
        self.scene = rtcs.EmbreeScene()
        tri = (self.V - self.origin)[self.F].astype(np.float32)
        TriangleMesh(self.scene, tri)

    def intersect(self, origins, dirs, max_dist):
        """First hit of each ray within ``max_dist``.

        Returns
        -------
        t : (k,) float64 distance (nan where missed)
        face : (k,) int64 (-1 where missed)
        bary : (k, 3) float64 barycentric coordinates of the hit in ``F[face]``
        """
        tfar, face, u, v = self.trace(np.asarray(origins, dtype=np.float64) - self.origin, dirs, max_dist)
        t = np.where(face >= 0, tfar.astype(np.float64), np.nan)
        return t, face.astype(np.int64), _bary(u, v)

    def trace(self, o, d, max_dist):
        """Raw Embree hits of rays from ``o`` (re-centred) along ``d``: tfar, primID, u, v
        (float32, int32, float32, float32; primID -1 where missed)."""
        o = np.ascontiguousarray(o, dtype=np.float32)
        d = np.ascontiguousarray(d, dtype=np.float32)
        dist = np.full(len(o), float(max_dist), dtype=np.float32)
        # embreex releases the GIL while tracing: split big batches over the cores (rays are
        # independent, so the results do not depend on the split)
        n_par = max(1, min(os.cpu_count() or 1, 8, len(o) // 100_000))
        if n_par == 1:
            parts = [self.scene.run(o, d, dists=dist, output=1)]
        else:
            from concurrent.futures import ThreadPoolExecutor

            bounds = np.linspace(0, len(o), n_par + 1).astype(np.int64)
            with ThreadPoolExecutor(n_par) as ex:
                parts = list(ex.map(lambda ab: self.scene.run(o[ab[0]:ab[1]], d[ab[0]:ab[1]],
                                                             dists=dist[ab[0]:ab[1]], output=1),
                                    zip(bounds[:-1], bounds[1:])))

        def col(name):
            return np.concatenate([np.asarray(p[name]) for p in parts])

        return col("tfar"), col("primID"), col("u"), col("v")


def _bary(u, v):
    """Barycentric coordinates (k, 3) float64 of Embree's hit coordinates ``u``, ``v``."""
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    bary = np.empty((len(u), 3))
    bary[:, 0] = 1.0 - u - v
    bary[:, 1] = u
    bary[:, 2] = v
    return bary


#: texels per piece of the chunked per-texel steps: 64k texels' temporaries (a few MB) stay in
#: the cache and are reused by the allocator; whole-array steps over the 2M texels of a 2048
#: map made and dropped 50-100 MB temporaries, and their page faults (kernel time) cost as much
#: as the arithmetic
CHUNK = 1 << 16


def in_chunks(k: int, fn, chunk: int = CHUNK) -> None:
    """Call ``fn(a, b)`` for consecutive ranges [a, b) covering ``range(k)``, ``chunk`` long,
    on up to two threads (numpy and Embree release the GIL). ``fn`` writes its own part of
    preallocated outputs, so the results do not depend on the order or the threads."""
    bounds = list(range(0, k, chunk)) + [k]
    parts = list(zip(bounds[:-1], bounds[1:]))
    n_threads = max(1, min(os.cpu_count() or 1, 2, len(parts)))
    if n_threads == 1:
        for a, b in parts:
            fn(a, b)
        return
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(n_threads) as ex:
        for _ in ex.map(lambda ab: fn(*ab), parts):      # re-raises a part's exception
            pass


def cast_both_ways(scene: DenseScene, P, N, max_dist, eps=1e-3):
    """Signed distance along the normal to the nearest surface hit, searching both directions.

    Rays start ``eps`` behind the point (so a surface through the point itself is
    found, not skipped by float32 rounding) and run ``max_dist + eps``; of the
    forward and backward hits the nearer one wins. Cast in pieces of :data:`CHUNK` points
    (each point's rays and answer are its own, so the same bits as in one batch).

    Returns
    -------
    disp : (k,) float64 signed distance (nan where both rays missed)
    face : (k,) int64, bary : (k, 3) float64 of the hit
    """
    P = np.asarray(P, dtype=np.float64)
    N = np.asarray(N, dtype=np.float64)
    k = len(P)
    disp = np.empty(k)
    face = np.empty(k, dtype=np.int64)
    bary = np.empty((k, 3))

    def part(a, b):
        p, n, m = P[a:b], N[a:b], b - a
        # forward rays from p - eps n, backward ones from p + eps n, re-centred in float64 and
        # then rounded to float32 (as Embree takes them)
        o = np.empty((2 * m, 3), dtype=np.float32)
        o[:m] = (p - eps * n) - scene.origin
        o[m:] = (p + eps * n) - scene.origin
        d = np.empty((2 * m, 3), dtype=np.float32)
        d[:m] = n
        np.negative(n, out=d[m:])
        tfar, f, u, v = scene.trace(o, d, max_dist + eps)
        # the nearer of the two hits, chosen first: only m of the 2m rays get float64 barycentrics
        t = np.where(f >= 0, tfar.astype(np.float64), np.nan)
        tf, tb = t[:m] - eps, t[m:] - eps
        use_b = np.isnan(tf) | (~np.isnan(tb) & (np.abs(tb) < np.abs(tf)))
        disp[a:b] = np.where(use_b, -tb, tf)
        sel = np.where(use_b, np.arange(m) + m, np.arange(m))
        face[a:b] = f[sel]
        bary[a:b] = _bary(u[sel], v[sel])

    in_chunks(k, part)
    return disp, face, bary
