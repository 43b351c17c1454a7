"""A tiny editable triangle mesh for local edits: edge collapses, boundary-edge splits and edge flips.

Python dicts, for the few hundred edits of the retopology's loop resampling and flip repairs
(:mod:`pipeline.retopo.eyelid_loop`, :mod:`pipeline.geometry.flips`).
"""

from __future__ import annotations

import numpy as np


class TriMesh:
    """Tiny editable triangle mesh for boundary collapses/splits (Python dicts; a few hundred ops)."""

    def __init__(self, V, F):
        self.V = [np.asarray(v, dtype=np.float64) for v in V]
        self.F = {i: list(map(int, f)) for i, f in enumerate(F)}
        self.vf = {}
        for fi, f in self.F.items():
            for v in f:
                self.vf.setdefault(v, set()).add(fi)
        self.next_f = len(F)

    def normal(self, f, pos=None):
        P = [self.V[v] if pos is None or v not in pos else pos[v] for v in f]
        n = np.cross(P[1] - P[0], P[2] - P[0])
        ln = np.linalg.norm(n)
        return n / ln if ln > 0 else n, 0.5 * ln

    def neighbours(self, v):
        out = set()
        for fi in self.vf.get(v, ()):
            out.update(self.F[fi])
        out.discard(v)
        return out

    def collapse(self, a, b, min_cos=0.2, ref=None):
        """Collapse vertex ``a`` into ``b`` (along an edge). Returns False if refused.

        ``ref`` (3,) optional reference normal the moved faces must agree with
        (used to repair faces that are already flipped)."""
        common = [fi for fi in self.vf[a] if b in self.F[fi]]
        if len(common) not in (1, 2):
            return False
        opp = {[v for v in self.F[fi] if v not in (a, b)][0] for fi in common}
        if self.neighbours(a) & self.neighbours(b) != opp:
            return False
        moved = [fi for fi in self.vf[a] if fi not in common]
        if not moved:
            return False
        for fi in moved:
            n0, _ = self.normal(self.F[fi])
            nf = [b if v == a else v for v in self.F[fi]]
            n1, area = self.normal(nf)
            if area <= 1e-12 or float((n0 if ref is None else ref) @ n1) < min_cos:
                return False
        for fc in common:
            for v in self.F[fc]:
                self.vf[v].discard(fc)
            del self.F[fc]
        for fi in moved:
            self.F[fi] = [b if v == a else v for v in self.F[fi]]
            self.vf[b].add(fi)
        self.vf[a] = set()
        return True

    def split(self, a, b, p):
        """Split boundary edge a->b (directed as in its face) at point ``p``; returns new vertex."""
        common = [fi for fi in self.vf[a] if b in self.F[fi]]
        fi = common[0]
        f = self.F[fi]
        c = [v for v in f if v not in (a, b)][0]
        # rotate so the face reads (x, y, c) with x->y the shared edge in face order
        k = f.index(c)
        x, y = f[(k + 1) % 3], f[(k + 2) % 3]
        m = len(self.V)
        self.V.append(np.asarray(p, dtype=np.float64))
        self.F[fi] = [x, m, c]
        self.vf[y].discard(fi)
        self.vf.setdefault(m, set()).add(fi)
        nf = self.next_f
        self.next_f += 1
        self.F[nf] = [m, y, c]
        for v in (m, y, c):
            self.vf[v].add(nf)
        return m

    def flip_edge(self, fi, a, c, ref=None, min_cos=0.05):
        """Flip edge a-c of face ``fi`` (which reads (a, b, c) cyclically) with its twin, if the two
        new faces agree with ``ref`` (default: the twin's normal); returns True when done."""
        f = self.F[fi]
        twins = [g for g in self.vf[a] & self.vf[c] if g != fi]
        if len(twins) != 1:
            return False
        b = [v for v in f if v not in (a, c)][0]
        k = f.index(b)
        a, c = f[(k - 1) % 3], f[(k + 1) % 3]
        g = twins[0]
        fg = self.F[g]
        d = [v for v in fg if v not in (a, c)][0]
        if d in self.neighbours(b):
            return False
        if ref is None:
            ref = self.normal(fg)[0]
        n1, ar1 = self.normal([a, b, d])
        n2, ar2 = self.normal([b, c, d])
        if ar1 <= 1e-12 or ar2 <= 1e-12 or n1 @ ref <= min_cos or n2 @ ref <= min_cos:
            return False
        for v in f:
            self.vf[v].discard(fi)
        for v in fg:
            self.vf[v].discard(g)
        self.F[fi] = [a, b, d]
        self.F[g] = [b, c, d]
        for v in (a, b, d):
            self.vf[v].add(fi)
        for v in (b, c, d):
            self.vf[v].add(g)
        return True

    def flip_ears(self, min_cos=0.0):
        """Flip away 'ear' triangles (a boundary vertex with a single face) where possible."""
        flipped = 0
        for b in [v for v, fs in self.vf.items() if len(fs) == 1]:
            if len(self.vf[b]) != 1:
                continue
            fi = next(iter(self.vf[b]))
            f = self.F[fi]
            k = f.index(b)
            a, c = f[(k - 1) % 3], f[(k + 1) % 3]       # face reads (a, b, c)
            flipped += self.flip_edge(fi, a, c, min_cos=min_cos)
        return flipped

    def arrays(self):
        F = np.array(list(self.F.values()), dtype=np.int64)
        V = np.array(self.V, dtype=np.float64)
        used = np.unique(F)
        remap = -np.ones(len(V), dtype=np.int64)
        remap[used] = np.arange(len(used))
        return V[used], remap[F], remap
