"""Batched ray casting against the dense scan with Embree (embreex), float32-safe."""

from __future__ import annotations

import os

import numpy as np


class DenseScene:
    """An Embree scene of a dense triangle mesh, re-centred before the float32 conversion.

    Parameters
    ----------
    V : (n, 3) float64, F : (m, 3) int64
    """

    def __init__(self, V, F):
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh

        self.V = np.asarray(V, dtype=np.float64)
        self.F = np.asarray(F, dtype=np.int64)
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
        o = np.ascontiguousarray(np.asarray(origins, dtype=np.float64) - self.origin, dtype=np.float32)
        d = np.ascontiguousarray(dirs, dtype=np.float32)
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

        def col(name, dtype):
            return np.concatenate([np.asarray(p[name], dtype=dtype) for p in parts])

        face = col("primID", np.int64)
        hit = face >= 0
        t = np.where(hit, col("tfar", np.float64), np.nan)
        u = col("u", np.float64)
        v = col("v", np.float64)
        bary = np.stack([1.0 - u - v, u, v], axis=1)
        return t, face, bary


def cast_both_ways(scene: DenseScene, P, N, max_dist, eps=1e-3):
    """Signed distance along the normal to the nearest surface hit, searching both directions.

    Rays start ``eps`` behind the point (so a surface through the point itself is
    found, not skipped by float32 rounding) and run ``max_dist + eps``; of the
    forward and backward hits the nearer one wins.

    Returns
    -------
    disp : (k,) float64 signed distance (nan where both rays missed)
    face : (k,) int64, bary : (k, 3) float64 of the hit
    """
    P = np.asarray(P, dtype=np.float64)
    N = np.asarray(N, dtype=np.float64)
    k = len(P)
    o = np.concatenate([P - eps * N, P + eps * N])
    d = np.concatenate([N, -N])
    t, face, bary = scene.intersect(o, d, max_dist + eps)
    tf, tb = t[:k] - eps, t[k:] - eps
    use_b = np.isnan(tf) | (~np.isnan(tb) & (np.abs(tb) < np.abs(tf)))
    disp = np.where(use_b, -tb, tf)
    sel = np.where(use_b, np.arange(k) + k, np.arange(k))
    return disp, face[sel], bary[sel]
