"""OMPL's PRM on a grid map from Python: the peer that ``lsd_prm.py`` and ``lsd_speed.py`` time.

Not a benchmark itself (the leading underscore keeps it out of the script listings); the
scripts import it as a sibling module.
"""

from __future__ import annotations

import functools
import importlib.metadata
import time

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph


def edge_degree(src, dst, m):
    """Mean number of distinct undirected edges per vertex."""
    a, b = np.minimum(src, dst), np.maximum(src, dst)
    return 2.0 * len(np.unique(a.astype(np.int64) * (m + 2) + b)) / max(m, 1)


def ompl_version() -> str:
    try:
        return importlib.metadata.version("ompl")
    except importlib.metadata.PackageNotFoundError:
        return "(version unknown)"


class OmplPRM:
    """OMPL's PRM on a grid map from Python, grown to exactly ``n`` milestones.

    ``trivial``: ``AllValidStateValidityChecker`` instead of the grid (OMPL's C++ core alone, checks
    nothing). ``seed``: seeds OMPL's RNG and quiets its log below errors; ``None`` leaves both as
    they are.
    """

    def __init__(self, b, n, k=10, trivial=False, seed=None):
        from ompl import base as ob, geometric as og, util as ou

        if seed is not None:
            ou.RNG.setSeed(int(seed) + 1)
            ou.setLogLevel(ou.LOG_ERROR)
        occ, res = b.occupancy, b.resolution
        H, W = occ.shape
        ox, oy = float(b.origin[0]), float(b.origin[1])
        space = ob.RealVectorStateSpace(2)
        bounds = ob.RealVectorBounds(2)
        bounds.setLow(0, ox)
        bounds.setHigh(0, ox + W * res)
        bounds.setLow(1, oy)
        bounds.setHigh(1, oy + H * res)
        space.setBounds(bounds)
        si = ob.SpaceInformation(space)
        if trivial:
            si.setStateValidityChecker(ob.AllValidStateValidityChecker(si))
        else:

            def valid(s):
                c, r = int((s[0] - ox) / res), int((s[1] - oy) / res)
                return bool(0 <= r < H and 0 <= c < W and not occ[r, c])  # OMPL needs a real bool

            si.setStateValidityChecker(valid)
        si.setStateValidityCheckingResolution(0.5 * res / space.getMaximumExtent())
        si.setup()
        pdef = ob.ProblemDefinition(si)
        planner = og.PRM(si)
        planner.setProblemDefinition(pdef)
        planner.setMaxNearestNeighbors(k)
        planner.setup()
        t0 = time.perf_counter()
        # Exactly n milestones: growRoadmap runs in this thread, so a Python condition is safe
        # here (PRM::solve's second thread is what deadlocks on one); it costs one call per
        # milestone, against hundreds of validity-checker calls per milestone.
        planner.growRoadmapPtc(ob.PlannerTerminationCondition(lambda: planner.milestoneCount() >= n))
        self.build_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        pd = ob.PlannerData(si)
        planner.getPlannerData(pd)
        M = pd.numVertices()
        self.pts = np.array([[pd.getVertex(i).getState()[0], pd.getVertex(i).getState()[1]] for i in range(M)])
        src, dst = [], []
        for i in range(M):
            for j in pd.getEdges(i):
                src.append(i)
                dst.append(j)
        self.src, self.dst = np.array(src, np.int64), np.array(dst, np.int64)
        self.extract_s = time.perf_counter() - t0
        self.M, self.k, self.si = M, k, si

    @functools.cached_property
    def degree(self):
        """Mean distinct undirected edges per milestone."""
        return edge_degree(self.src, self.dst, self.M)

    def query(self, start, goal, with_path=True):
        """(seconds, found, length, points): start and goal linked to their k nearest milestones
        with ``checkMotion``, then scipy Dijkstra. ``points`` is ``None`` unless ``with_path``
        (its predecessors are then searched inside the clock, the path walked after it)."""
        t0 = time.perf_counter()
        si, M, pts = self.si, self.M, self.pts
        a, b = si.allocState(), si.allocState()
        src, dst = [self.src], [self.dst]
        for q_idx, q in ((M, start), (M + 1, goal)):
            d = np.linalg.norm(pts - q, axis=1)
            for j in np.argsort(d)[: self.k]:
                a[0], a[1] = float(q[0]), float(q[1])
                b[0], b[1] = float(pts[j, 0]), float(pts[j, 1])
                if si.checkMotion(a, b):
                    src.append(np.array([q_idx]))
                    dst.append(np.array([int(j)]))
        src, dst = np.concatenate(src), np.concatenate(dst)
        allp = np.vstack([pts, start, goal])
        w = np.maximum(np.linalg.norm(allp[src] - allp[dst], axis=1), 1e-12)
        g = scipy.sparse.csr_matrix((w, (src, dst)), shape=(M + 2, M + 2))
        if not with_path:
            dist = scipy.sparse.csgraph.dijkstra(g, directed=False, indices=M)
            return time.perf_counter() - t0, bool(np.isfinite(dist[M + 1])), float(dist[M + 1]), None
        dist, pred = scipy.sparse.csgraph.dijkstra(g, directed=False, indices=M, return_predecessors=True)
        elapsed = time.perf_counter() - t0
        found = bool(np.isfinite(dist[M + 1]))
        path = []
        if found:  # after the clock: the path's points are for the edge-rule check only
            v = M + 1
            while v >= 0:
                path.append(allp[v])
                v = pred[v]
        return elapsed, found, float(dist[M + 1]), np.array(path[::-1]).reshape(-1, 2)
