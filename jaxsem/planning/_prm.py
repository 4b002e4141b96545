"""The host-side :class:`PRM` most users want: a roadmap built once, grown, rechecked against a
growing map and queried many times (:mod:`jaxsem.planning._roadmap` has the pure pieces).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ._edges import _edge_samples, _host_edges
from ._grid import UNKNOWN, GridLike, check_point, host_grid, static_grid
from ._lazy import _CHUNK, _checker, _grow_checked_host, _grow_host_weighed, _grow_lazy, _LazyEdges
from ._map_setup import _map_setup
from ._roadmap import (
    _QUERY,
    DEFAULT_SECTORS,
    Roadmap,
    _as_dist,
    _blocked_from,
    _check_distribution,
    _check_sectors,
    _edge_cost_jit,
    _grow_exact,
    _initial_cap,
    _links_checked,
    _query_table,
    _recheck_jit,
    _strip_cap,
    _with_query_jit,
    default_radius,
    prm_star_k,
    roadmap_init,
)
from ._roadmap_search import RoadmapPath, RoadmapPaths, _SampleGraph, _search_rows
from ._sampling import LocalDistribution

#: Roadmaps up to this many vertices search neighbours by brute force when their samples come from
#: a distribution: a search over every vertex costs little at this size, and the strips' slots,
#: sized to each distribution, would compile a program per size.
_BRUTE_FORCE_MAX = 4096


class PRM:
    """A roadmap on a partial map that is built once, grown, rechecked and queried many times.

    known_map: (H, W) int8 partial map or bool obstacle grid; grid: its
    :class:`jaxsem.quadrics.Grid` (origin, resolution, shape) or a map holding one (``.grid``:
    :class:`~jaxsem.planning.Building`, :class:`~jaxsem.planning.OccupancyGrid`); capacity: most samples it will hold (fixed
    shapes: growing never recompiles); k: neighbours per vertex (None: :func:`prm_star_k` of
    ``capacity``); radius: connection radius in
    metres (None: :func:`default_radius` of ``capacity`` over the cells not known occupied); weight: 'euclidean' or 'neglogp'
    (edge weights from the distribution given to :meth:`grow`; the latest one also weights the
    query's edges); sectors: 0 (each vertex links to its k nearest) or the direction sectors
    whose nearest come first (module docstring); lazy: check no edge when growing, only those
    a query's shortest path needs (Lazy PRM, :mod:`jaxsem.planning._lazy`; the same roadmap and
    the same shortest paths as the eager PRM, Euclidean weights only; checked edges are kept for
    later queries). Methods: :meth:`grow`, :meth:`update_map`, :meth:`query`, :meth:`query_many` (a
    batch of queries in one call); the pytree is
    :attr:`roadmap` (with ``lazy``, its samples' edges are empty: :meth:`checked_roadmap` checks
    them all and returns the eager roadmap). The per-map setup (uniform sampling's free-cell words;
    the edge check's clearance table, made on first use: a lazy PRM's first query needs it only
    around its start and goal; a second query, a batch, :meth:`checked_roadmap` or
    :meth:`update_map` make the whole map's, which later queries share) is kept for the latest two maps, matched cell for cell, so several roadmaps on one
    map make it once (:func:`~jaxsem.planning.clear_map_cache` forgets it).

    Where the edges are checked: on the device, or, for float32 points (JAX's default), on the
    host by the same rule compiled with numba (:mod:`jaxsem.planning._edges_kernels`), whose
    float32 samples are probed once per process to fall in the device's cells: a query's links
    and a lazy roadmap's edges always, an eager grow's with Euclidean weights (the first ``k``
    clear candidates of each vertex, read in order over numba's threads). The roadmap and the
    paths are the same either way.

    unknown_weight: what a metre through an unknown cell costs against one through a known free
    cell (1: the same, the thesis' rule). Above 1 the planner stays optimistic about unknown
    cells (they are still free to cross) but prefers a route it has seen free to an equally long
    one through unknown space; the edges' weights follow :meth:`update_map`. Needs an int8
    partial map (a bool grid has no unknown cells) and an eager roadmap (weights read every
    sample of an edge, so ``lazy`` gains nothing).

    reach: the length (m) over which a query's start and goal links longer than ``radius`` are
    sampled (None: the map's diagonal rounded up to a power of two). A caller that pads its map
    (the navigation loop pads every map to a size bucket, so one compiled program serves maps of
    several shapes) passes its unpadded map's, so the links are checked as on that map.
    """

    def __init__(
        self,
        known_map,
        grid: GridLike,
        *,
        capacity: int,
        k: int | None = None,
        radius: float | None = None,
        weight: str = "euclidean",
        sectors: int = DEFAULT_SECTORS,
        lazy: bool = False,
        unknown_weight: float = 1.0,
        reach: float | None = None,
    ):
        blocked = _blocked_from("known_map", known_map)
        if not isinstance(lazy, bool):
            raise ValueError(f"lazy: expected a bool, got {lazy!r}")
        if lazy and weight != "euclidean":
            raise ValueError(f"lazy: needs weight='euclidean' (edge weights known before the check), got {weight!r}")
        if not (
            isinstance(unknown_weight, (int, float, np.floating))
            and not isinstance(unknown_weight, bool)
            and 0 < unknown_weight < np.inf
        ):
            raise ValueError(f"unknown_weight: expected a finite number > 0, got {unknown_weight!r}")
        self.unknown_weight = float(unknown_weight)
        if self.unknown_weight != 1.0 and lazy:
            raise ValueError("lazy: needs unknown_weight=1 (edge weights known before the check)")
        self._unknown = self._unknown_cells(known_map)
        self.sectors = _check_sectors(sectors)
        self.grid = host_grid("grid", grid, blocked.shape)
        if weight not in ("euclidean", "neglogp"):
            raise ValueError(f"weight: expected 'euclidean' or 'neglogp', got {weight!r}")
        self._pending = None
        self._points: np.ndarray | None = None
        # The host's copy of the roadmap's points and sample rows (neighbours, valid flags,
        # weights), kept where the host wrote them (an eager grow checked on the host): the
        # queries' search graph is made from it without reading the device's roadmap back.
        self._rows: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._queries = 0
        self.roadmap = roadmap_init(capacity, prm_star_k(capacity) if k is None else k)
        self.blocked = blocked
        self._factor = self._factor_grid()
        self._cost = None  # the cell cost the weights integrate, made once per distribution and map
        self._setup = _map_setup(blocked, self.roadmap.points.dtype, owned=_made_here(blocked, known_map))
        self._blocked_j = self._setup.blocked_j
        self._free_cells = self._setup.free_cells
        self.radius = (
            float(radius)
            if radius is not None
            else default_radius(capacity, blocked.shape, self.resolution, weight, free_cells=self._free_cells)
        )
        if reach is not None and not (isinstance(reach, (int, float, np.floating)) and 0 < reach < np.inf):
            raise ValueError(f"reach: expected None or a finite length > 0 (m), got {reach!r}")
        self.reach = None if reach is None else float(reach)
        self.weight = weight
        self.distribution = None
        self._cap: int | None = None
        self._graph: _SampleGraph | None = None
        self.lazy = lazy
        self._lazy: _LazyEdges | None = None
        if lazy:
            M, k = self.roadmap.neighbors.shape
            self._lazy = _LazyEdges(M, 2 * k if self.sectors else k, k)

    def _unknown_cells(self, known_map) -> np.ndarray | None:
        """The map's unknown cells when ``unknown_weight`` is not 1 (None otherwise)."""
        if self.unknown_weight == 1.0:
            return None
        arr = np.asarray(known_map)
        if arr.dtype != np.int8:
            raise ValueError(
                f"known_map: unknown_weight={self.unknown_weight} needs an int8 partial map "
                f"(UNKNOWN/FREE/OCCUPIED), got dtype {arr.dtype}"
            )
        return arr == UNKNOWN

    def _factor_grid(self):
        if self._unknown is None:
            return None
        return jnp.where(jnp.asarray(self._unknown), self.unknown_weight, 1.0).astype(self.roadmap.points.dtype)

    @property
    def roadmap(self) -> Roadmap:
        """The roadmap pytree, its rows 0 and 1 the latest query's (written on first read after
        a query: a query itself keeps its rows on the host)."""
        if self._pending is not None:
            self._roadmap = _with_query_jit(self._roadmap, *self._pending)
            self._pending = None
        return self._roadmap

    @roadmap.setter
    def roadmap(self, value: Roadmap) -> None:
        self._roadmap = value
        self._pending = None
        self._points = None
        self._rows = None

    @property
    def origin(self) -> np.ndarray:
        """(2,) float64 world (x, y) of cell [0, 0]'s corner (:attr:`grid`'s)."""
        return np.asarray(self.grid.origin, np.float64)

    @property
    def resolution(self) -> float:
        """Metres per cell (:attr:`grid`'s)."""
        return float(self.grid.resolution)

    @property
    def count(self) -> int:
        """Samples in the roadmap."""
        return int(self._roadmap.num_samples)

    @property
    def capacity(self) -> int:
        return int(self._roadmap.points.shape[0]) - _QUERY

    def grow(self, key, n: int, distribution=None, *, uniform_samples: bool = False) -> int:
        """Adds ``n`` samples from ``distribution`` ((H, W) cell weights, or a
        :class:`~jaxsem.planning.LocalDistribution` standing for them; None: uniform over the
        cells not known occupied). ``uniform_samples``: draw the samples uniformly even so (the
        distribution still weights the edges under ``weight='neglogp'``). Returns the sample
        count."""
        if self.weight == "neglogp" and distribution is None:
            distribution = self.distribution
        if self.weight == "neglogp" and distribution is None:
            raise ValueError("distribution: weight='neglogp' needs a distribution, got None")
        if not (isinstance(n, (int, np.integer)) and n >= 1):
            raise ValueError(f"n: expected a positive int number of samples, got {n!r}")
        if self.count + int(n) > self.capacity:
            raise ValueError(f"n: {n} more samples exceed the capacity ({self.capacity}, {self.count} used)")
        distribution = _check_distribution(distribution, self.blocked.shape)
        dtype = self.roadmap.points.dtype
        dist = _as_dist(distribution, dtype)
        cap = self._cap or _initial_cap(
            self.capacity, self.blocked.shape, self.resolution, self.radius, self._free_cells
        )
        if distribution is not None and not uniform_samples:
            if self.capacity + _QUERY <= _BRUTE_FORCE_MAX:
                cap = self.capacity  # every vertex a candidate: one program whatever the distribution
            else:
                full = (
                    distribution.full(self.blocked.shape)
                    if isinstance(distribution, LocalDistribution)
                    else distribution
                )
                weights = np.where(self.blocked, 0.0, full)
                cap = max(cap, _strip_cap(weights, self.count + int(n), self.resolution, self.radius))
        # The lazy and eager grows take the same samples (the eager grow also weighs its edges).
        args = (self.roadmap, key, self._blocked_j, dist, self.grid, int(n), self.radius, cap)
        if self._lazy is not None:
            s0 = _QUERY + self.count
            (self.roadmap, cand), self._cap = _grow_lazy(
                *args, self.sectors, bool(uniform_samples), self._setup.aids(table=False)
            )
            self._lazy.add_rows(s0, cand)
        elif self.weight == "euclidean" and self._factor is None and _host_edges(dtype):
            # Lengths as weights: the edges checked on the host, the same roadmap.
            if distribution is not None and distribution is not self.distribution:
                self.distribution, self._cost = distribution, None
            rows = self._rows if self._rows is not None else _host_rows(self._roadmap)
            self.roadmap, self._cap, (s0, pts, nbr, ev, w) = _grow_checked_host(
                *args[:2],
                self.blocked,
                *args[2:],
                self.sectors,
                bool(uniform_samples),
                self._setup.aids(table=False),
                np.asarray(self._setup.table()),
                self._setup.bits(),
            )
            for mine, new in zip(rows[1:], (nbr, ev, w), strict=True):
                mine[s0 : s0 + len(new)] = new
            self._rows = (pts, *rows[1:])
        elif self.weight == "neglogp" and self._factor is None and _host_edges(dtype):
            # Weights that integrate -log p: the edges checked on the host, weighed on the
            # device, the same roadmap.
            if distribution is not self.distribution:
                self.distribution, self._cost = distribution, None
            self.roadmap, self._cap = _grow_host_weighed(
                *args[:2],
                self.blocked,
                *args[2:],
                self.sectors,
                bool(uniform_samples),
                self._setup.aids(table=False),
                np.asarray(self._setup.table()),
                self._edge_cost(dist),
            )
        else:
            if distribution is not None and distribution is not self.distribution:
                self.distribution, self._cost = distribution, None
            self.roadmap, self._cap = _grow_exact(
                *args,
                self.weight == "neglogp",
                self.sectors,
                bool(uniform_samples),
                self._setup.aids(table=True),
                factor=self._factor,
                cost=self._edge_cost(dist),
            )
        if distribution is not None:
            self.distribution = distribution
        self._graph = None
        return self.count

    def update_map(self, known_map) -> bool:
        """Adopts a newer partial map; drops vertices and edges it blocks (only where something
        changed: an unchanged map costs nothing; with ``unknown_weight`` the kept edges are
        weighed again when cells became known). Returns True if the map changed. With ``lazy``
        the links are first settled on the old map (every unchecked edge is checked there, as the
        eager grow did), so lazy saves nothing on a map that changes between queries."""
        blocked = _blocked_from("known_map", known_map)
        if blocked.shape != self.blocked.shape:
            raise ValueError(f"known_map: expected shape {self.blocked.shape}, got shape {blocked.shape}")
        unknown = self._unknown_cells(known_map)
        same_unknown = unknown is None or self._unknown is None or np.array_equal(unknown, self._unknown)
        if np.array_equal(blocked, self.blocked) and same_unknown:
            return False
        if self._lazy is not None:
            # The eager PRM chose its links on the old map: settle them there first (this
            # checks every edge no query has checked yet).
            self._lazy.settle(self._check_fn(chunk=16384))
        self.blocked = blocked
        self._unknown = unknown
        self._factor = self._factor_grid()
        self._cost = None
        self._setup = _map_setup(blocked, self.roadmap.points.dtype, owned=_made_here(blocked, known_map))
        self._blocked_j = self._setup.blocked_j
        self._free_cells = self._setup.free_cells
        # With a factor grid the kept edges are weighed again (their cells may have become known).
        reweigh = self._factor is not None
        dtype = self.roadmap.points.dtype
        dist = _as_dist(self.distribution, dtype) if reweigh else None
        self.roadmap = _recheck_jit(
            self.roadmap,
            self._blocked_j,
            static_grid(self.grid),
            dist,
            self._factor,
            edge_samples=_edge_samples(self.radius, self.resolution),
            neglogp=reweigh and self.weight == "neglogp",
        )
        if self._lazy is not None:
            self._lazy.forget_clear(np.asarray(self.roadmap.valid))
        self._graph = None
        return True

    def query(self, start, goal) -> RoadmapPath:
        """Shortest roadmap path from ``start`` to ``goal`` (world (2,), not known occupied)."""
        start = check_point("start", start, self.blocked, self.grid)
        goal = check_point("goal", goal, self.blocked, self.grid)
        return self._query(start[None], goal[None])[0]

    def query_many(self, starts, goals) -> RoadmapPaths:
        """Shortest roadmap paths of ``Q`` queries on this roadmap in one call: ``starts``,
        ``goals`` (Q, 2) world points, not known occupied. Every query's start and goal links
        are made and checked in one compiled call (a query's fixed cost paid once), then each
        is searched on the host; the paths are those of ``Q`` calls of :meth:`query` in order
        (with ``lazy``, the edges each search checks serve the next). Afterwards
        :attr:`roadmap`'s rows 0 and 1 are the last query's. Returns a padded
        :class:`RoadmapPaths` (``.path(i)``: query ``i``'s :class:`RoadmapPath`)."""
        starts_a, goals_a = _points_batch("starts", starts), _points_batch("goals", goals)
        if starts_a.shape != goals_a.shape:
            raise ValueError(f"goals: expected the shape of starts {starts_a.shape}, got shape {goals_a.shape}")
        for name, pts in (("starts", starts_a), ("goals", goals_a)):
            for i, p in enumerate(pts):
                check_point(f"{name}[{i}]", p, self.blocked, self.grid)
        return RoadmapPaths.stack(self._query(starts_a, goals_a))

    def _query(self, starts: np.ndarray, goals: np.ndarray) -> list[RoadmapPath]:
        """Links the queries (Q, 2) (checked points) in one call, then searches each in turn."""
        rm = self._roadmap
        if self._lazy is not None and not self._setup.has_table and len(starts) == 1 and self._queries == 0:
            # A lazy PRM's first query reads the table only around its start and goal; later
            # queries share the map's (made once).
            table = _query_table(rm, starts[0], goals[0], self._setup, self.grid, self.sectors)
        else:
            table = self._setup.table()
        q, nbr, ev, w = _links_checked(
            rm,
            starts,
            goals,
            self.blocked,
            self._blocked_j,
            self.grid,
            radius=self.radius,
            distribution=self.distribution,
            weight=self.weight,
            sectors=self.sectors,
            table=table,
            factor=self._factor,
            reach=self.reach,
            cost=self._edge_cost(),
            bits=self._setup.bits(make=False),
        )
        self._queries += len(q)
        if self._points is None:
            self._points = np.array(rm.points if self._rows is None else self._rows[0])
        if self._lazy is None and self._graph is None:
            rows = self._rows or (rm.points, rm.neighbors, rm.edge_valid, rm.edge_weight)
            self._graph = _SampleGraph(*rows)
        out = []
        for i in range(len(q)):
            if self._lazy is not None:
                self._points[:_QUERY] = q[i]
                out.append(self._lazy.search_rows(self._points, nbr[i], ev[i], w[i], self._check_fn()))
            else:
                assert self._graph is not None  # made above
                out.append(_search_rows(self._graph, q[i], nbr[i], ev[i], w[i]))
        self._pending = (q[-1], nbr[-1], ev[-1], w[-1])
        return out

    def _edge_cost(self, dist=None):
        """The cell cost the edge weights integrate (``-log p`` of the latest distribution under
        ``weight='neglogp'``, times the unknown cells' factor; None: lengths), made once per
        distribution and map: a grow and the queries after it read the same grid. ``dist``:
        that distribution on the device when the caller has it."""
        neglogp = self.weight == "neglogp"
        if self._cost is None and (neglogp or self._factor is not None):
            if dist is None and self.distribution is not None:
                dist = _as_dist(self.distribution, self.roadmap.points.dtype)
            if neglogp and dist is None:
                return None  # no distribution yet: the caller refuses (weight='neglogp' needs one)
            self._cost = _edge_cost_jit(dist, self._factor, neglogp)
        return self._cost

    def _check_fn(self, chunk: int | None = None):
        assert self._lazy is not None  # internal: only the lazy PRM checks edges on demand
        kw = {} if chunk is None else {"chunk": chunk}
        if self._points is None:
            self._points = np.array(self._roadmap.points)
        # A query's calls read every sample (no table); many edges at once read the table.
        return _checker(
            self.blocked,
            self._blocked_j,
            self._points,
            self._lazy.cand,
            static_grid(self.grid),
            None if chunk is None or chunk <= _CHUNK else self._setup.table(),
            _edge_samples(self.radius, self.resolution),
            bits=self._setup.bits(make=chunk is not None and chunk > _CHUNK),
            **kw,
        )

    def checked_roadmap(self) -> Roadmap:
        """The roadmap with every sample edge decided: with ``lazy``, checks the edges no query
        has checked yet and returns what the eager PRM builds from the same samples (the
        current query's rows as :attr:`roadmap` has them); without, :attr:`roadmap`."""
        if self._lazy is None:
            return self.roadmap
        self._lazy.check_all(self._check_fn(chunk=16384))
        dtype = self.roadmap.points.dtype
        nbr, ev, w = self._lazy.links(np.asarray(self.roadmap.points), dtype)
        rm = self.roadmap
        return rm._replace(
            neighbors=jnp.asarray(nbr).at[:_QUERY].set(rm.neighbors[:_QUERY]),
            edge_valid=jnp.asarray(ev).at[:_QUERY].set(rm.edge_valid[:_QUERY]),
            edge_weight=jnp.asarray(w).at[:_QUERY].set(rm.edge_weight[:_QUERY]),
        )


def _points_batch(name: str, pts) -> np.ndarray:
    """``pts`` as (Q, 2) float64 world points, Q >= 1, else ValueError naming ``name``."""
    try:
        arr = np.asarray(pts, np.float64)
    except Exception as exc:
        raise ValueError(f"{name}: cannot be converted to a float array ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 1:
        raise ValueError(f"{name}: expected world points (Q, 2) with Q >= 1, got shape {arr.shape}")
    return arr


def _host_rows(rm: Roadmap) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The roadmap's points, neighbours, valid flags and weights as (writable) numpy arrays."""
    return np.array(rm.points), np.array(rm.neighbors), np.array(rm.edge_valid), np.array(rm.edge_weight)


def _made_here(blocked: np.ndarray, known_map) -> bool:
    """Whether ``blocked`` (:func:`_blocked_from` of ``known_map``) is a grid made from a partial
    map here, not the caller's own bool grid: then the per-map setup keeps it without a copy."""
    return blocked is not known_map and np.asarray(known_map).dtype != np.bool_
