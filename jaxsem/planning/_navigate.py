"""The online loop of thesis section 3.3.3: plan, follow, sense, replan; and the local inputs.

Each timestep the robot turns towards the next point of its plan, senses (depth + object camera),
replans if the rest of the plan now crosses a known obstacle or if ``replan_every`` steps have
passed, then moves ``step_length`` metres along the plan. Because it senses facing the way it is
about to move (the depth sensor reaches 5 m, a step is 0.25 m), it never drives into an obstacle
it has not seen. A trial succeeds when the robot is within ``goal_tolerance`` of the goal; it
fails when a plan cannot be found or after ``max_steps`` steps.

Roadmap reuse and failed roadmaps. The loop keeps its :class:`~jaxsem.planning.PRM`. The uniform
planner's distribution never changes, so its roadmap (of ``n_samples``) is reused for every replan: the newer
partial map only removes the vertices and edges it blocks (and costs nothing where the map has
not changed), and the robot's position and the goal are connected as a new query. A learned
sampler's window moves with the robot, so each replan samples a new roadmap from the current
distribution (thesis 3.2.5). When a roadmap has no path, it is grown by ``n_samples`` more
samples from the current distribution, up to ``max_growth`` times; a trial fails with
'no_plan' only when the largest roadmap still has none (``max_growth=0`` is the thesis' rule:
the first failed roadmap ends the trial). ``NavResult.grown`` counts the growths. Reuse and
growth are this library's defaults, not the thesis': its protocol as written (3.3.3) draws a
fresh roadmap at every replan for both planners and ends a trial at the first roadmap without a
path, ``NavConfig(reuse_roadmap=False, max_growth=0)`` (``benchmarks/lsd/lsd_table31.py --ablations
thesis`` runs both planners so, beside the defaults).

Sampling: ``sampler=None`` is the uniform PRM with Euclidean edge weights (PRM + Unf). Otherwise
``sampler(inputs: LocalInputs) -> (160, 160)`` probabilities over the robot-centred window
(e.g. the LSD network's softmax); the window stands for the full map's distribution (outside:
the window's minimum, renormalised, section 3.2.5), held as a
:class:`~jaxsem.planning.LocalDistribution` so that no grid of the map's size is made per replan;
the PRM samples from it, and edges are weighted by the integral of ``-log p``
(``edge_weight='neglogp'``, eq. 3.3) unless told otherwise. Both planners
link vertices direction-first (``NavConfig.sectors``; see :mod:`jaxsem.planning._roadmap`), and a
learned sampler's roadmap gets twice the uniform radius (``learned_radius_factor``): outside the
window its few samples are too far apart for the uniform radius, which ended most Inside-Outside
trials with 'no_plan' (``benchmarks/lsd/lsd_diagnose_finding.md``).

Where the loop runs: sensing, crops, sampling, neighbour search and edge checks are jitted JAX
(and vmappable: ``sense`` and the roadmap builder take batches); the graph search is a compiled
A* on the host, and so is the control flow of a trial, which is why trials run one after
another (:func:`navigate`) rather than under ``vmap``; :func:`jaxsem.lsd.run_trials` with a
``mesh`` deals whole trials over devices instead (one host thread per device). Per step the host
work is a few milliseconds; see ``benchmarks/lsd/lsd_speed.py``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import quadrics as Q
from ._edges import polyline_clear, query_reach
from ._grid import (
    FREE,
    NONE,
    OCCUPIED,
    UNKNOWN,
    GridLike,
    MapState,
    _grid,
    check_grid,
    check_point,
    empty_map_state,
    host_grid,
    static_grid,
)
from ._prm import PRM
from ._roadmap import DEFAULT_SECTORS, LEARNED_RADIUS_FACTOR, default_radius, prm_star_k
from ._sampling import LocalDistribution, embed_local_distribution
from ._sensors import SensorConfig, _check_resolution, _sense_in_place, _sense_jit, _sense_sizes

CROP_SIZE = 160
CONTEXT_SIZE = 4


class LocalInputs(NamedTuple):
    """What a learned sampler sees (one robot; batch axes may lead when stacked).

    occupancy: (160, 160) int8 partial occupancy crop centred on the robot's cell (the robot is
        at crop cell [80, 80]); UNKNOWN -1 / FREE 0 / OCCUPIED 1; off the map: OCCUPIED.
    semantic: (160, 160) int8 partial semantic crop (NONE 0, DOOR 2, WINDOW 3, EXIT_SIGN 4).
    context: (4,) float32 [cos a, sin a, min(d, d_max) / d_max, goal_outdoors], a the world
        heading of the goal from the robot (x along crop columns, y along crop rows), d its
        distance in metres, goal_outdoors 1.0 for a goal outside the building else 0.0.
    center_cell: (2,) int32 (row, col) of the robot in the full map.
    """

    occupancy: jax.Array
    semantic: jax.Array
    context: jax.Array
    center_cell: jax.Array


@functools.partial(jax.jit, static_argnames=("grid", "size", "max_distance"))
def _local_inputs(occupancy, semantic, xy, goal, goal_outdoors, grid, size, max_distance):
    grid = _grid(grid, xy.dtype)
    rc = Q.world_to_cell(xy, grid.origin, grid.resolution)
    pad = size
    occ = jnp.pad(occupancy, pad, constant_values=OCCUPIED)
    sem = jnp.pad(semantic, pad, constant_values=NONE)
    r0, c0 = rc[0] - size // 2 + pad, rc[1] - size // 2 + pad
    occ_c = jax.lax.dynamic_slice(occ, (r0, c0), (size, size))
    sem_c = jax.lax.dynamic_slice(sem, (r0, c0), (size, size))
    d = goal - xy
    dist = jnp.sqrt(jnp.sum(d**2) + 1e-12)  # safe: the goal may coincide with the robot
    ctx = jnp.stack(
        [
            d[0] / dist,
            d[1] / dist,
            jnp.minimum(dist, max_distance) / max_distance,
            goal_outdoors.astype(dist.dtype),
        ]
    ).astype(jnp.float32)
    return LocalInputs(occ_c, sem_c, ctx, rc)


@functools.partial(jax.jit, static_argnames=("scale",))
def _pooled_state(state: MapState, scale: int) -> MapState:
    """The partial maps at ``scale`` times the cell size: a cell is occupied if any of its
    ``scale x scale`` cells is, else free if any is, else unknown; its semantic class is the
    largest code among them. Off-map padding (bottom, right) is unknown."""
    H, W = state.occupancy.shape
    Hp, Wp = -(-H // scale) * scale, -(-W // scale) * scale

    def blocks(x, fill):
        x = jnp.pad(x, ((0, Hp - H), (0, Wp - W)), constant_values=fill)
        return x.reshape(Hp // scale, scale, Wp // scale, scale)

    occ = blocks(state.occupancy, UNKNOWN)
    pooled = jnp.where(
        jnp.any(occ == OCCUPIED, axis=(1, 3)), OCCUPIED, jnp.where(jnp.any(occ == FREE, axis=(1, 3)), FREE, UNKNOWN)
    )
    return MapState(pooled.astype(jnp.int8), jnp.max(blocks(state.semantic, NONE), axis=(1, 3)))


@functools.partial(jax.jit, static_argnames=("scale", "shape"))
def _unpooled(dist, scale: int, shape):
    """A pooled map's cell weights spread evenly over its cells' ``scale x scale`` cells of the
    full map ``shape``, renormalised."""
    H, W = shape
    full = jnp.repeat(jnp.repeat(dist, scale, axis=0), scale, axis=1)[:H, :W]
    return full / jnp.sum(full)


#: :func:`embed_local_distribution` in one compiled call (op by op, each of its steps is a pass
#: over the whole map).
_embed_jit = jax.jit(embed_local_distribution, static_argnames=("full_shape", "outside_mass"))
_full_jit = jax.jit(LocalDistribution.full, static_argnums=1)


@jax.jit
def _cell_at(grid, row, col):
    """One cell of a device grid (a jitted read: indexing the array from the host dispatches
    several operations per read)."""
    return grid[row, col]


def _bucket_side(n: int, bucket: int) -> int:
    """``n`` rounded up to the next rung of the ladder 32, 48, 64, 96, 128, 192, ... below
    ``bucket`` (each rung 4/3 or 3/2 of the last: at most half again as many cells), to ``bucket``
    itself, or, at or above ``bucket``, to a multiple of it."""
    if bucket <= 1:
        return n
    if n >= bucket:
        return -(-n // bucket) * bucket
    rung = 32
    while rung < n and rung < bucket:
        rung = rung * 3 // 2 if rung & (rung - 1) == 0 else rung * 4 // 3
    return min(max(rung, n), bucket)


def bucket_shape(shape, bucket: int) -> tuple[int, int]:
    """``shape`` (H, W) with each side rounded up to its size bucket: the shape the navigation
    loop's compiled steps see (:attr:`NavConfig.shape_bucket`). A side below ``bucket`` cells goes
    to the next of 32, 48, 64, 96, 128, 192, ... (so a small map is not padded to a large one's
    size), a longer one to a multiple of ``bucket``."""
    b = max(1, int(bucket))
    return (_bucket_side(int(shape[0]), b), _bucket_side(int(shape[1]), b))


def _padded(x, shape, fill) -> jax.Array:
    """``x`` (H, W) padded at the bottom and right to ``shape`` with ``fill`` (on the host: an
    eager pad compiles a program per shape) on the device; a JAX ``x`` itself when it has
    ``shape``."""
    H, W = x.shape[-2:]
    if (H, W) == tuple(shape):
        return jax.device_put(x)
    return jax.device_put(np.pad(np.asarray(x), ((0, shape[0] - H), (0, shape[1] - W)), constant_values=fill))


def _unpadded(x, shape):
    """The leading ``shape`` (H, W) of a padded grid ``x``, through the host as :func:`_padded`
    (``device_put``: ``jnp.asarray`` of a host array compiles a copy per shape)."""
    return jax.device_put(np.ascontiguousarray(np.asarray(x)[: shape[0], : shape[1]]))


def local_inputs(
    state: MapState,
    xy,
    goal,
    goal_outdoors,
    grid: GridLike,
    size: int = CROP_SIZE,
    max_distance: float = 20.0,
) -> LocalInputs:
    """Robot-centred crops of the partial maps plus the goal context (see :class:`LocalInputs`).

    state: :class:`MapState` (H, W); xy, goal: (2,) world (x, y); goal_outdoors: bool; grid:
    the state's :class:`jaxsem.quadrics.Grid` (or a map holding one, e.g. a
    :class:`~jaxsem.planning.Building`); max_distance: metres at which the context's distance
    saturates. Jitted.
    """
    grid = host_grid("grid", grid, state.occupancy.shape[-2:])
    dtype = jnp.result_type(float)
    return _local_inputs(
        state.occupancy,
        state.semantic,
        jnp.asarray(xy, dtype),
        jnp.asarray(goal, dtype),
        jnp.asarray(goal_outdoors, bool),
        static_grid(grid),
        int(size),
        float(max_distance),
    )


@dataclasses.dataclass(frozen=True)
class NavConfig:
    """Settings of the online loop (thesis 3.3.3 defaults where it gives them)."""

    n_samples: int = 500
    k: int | None = None  # PRM neighbours per vertex; None: prm_star_k(n_samples)
    # PRM connection radius (m); None: default_radius(n_samples) for the uniform sampler and
    # learned_radius_factor times that for a learned one (see Trial.radius).
    radius: float | None = None
    learned_radius_factor: float = LEARNED_RADIUS_FACTOR
    step_length: float = 0.25  # metres moved per timestep
    replan_every: int = 20  # planning timesteps a plan is followed before replanning
    max_steps: int = 10_000
    goal_tolerance: float = 0.2
    edge_weight: str | None = None  # None: 'euclidean' (uniform) / 'neglogp' (learned sampler)
    max_growth: int = 2  # a roadmap without a path grows by n_samples up to this many times
    # what a failed roadmap grows with: "sampler" (the planner's own distribution: the thesis'
    # rule) or "uniform" (uniform samples, a variant for a learned sampler; edges keep its weights)
    growth: str = "sampler"
    # what the cells outside a learned sampler's window get: None (the window's minimum, the
    # thesis' rule) or (q indoors, q outdoors): the share of the mass spread evenly outside the
    # window when the goal is indoors / outdoors (a variant; embed_local_distribution)
    outside_mass: tuple[float, float] | None = None
    # PRM links chosen by direction first (the nearest in each of 8 sectors, then the nearest):
    # 0 is the plain k nearest, which left LSD's dense clusters and sparse outside unlinked.
    sectors: int = DEFAULT_SECTORS
    # the cell size a learned sampler sees, in map cells: 1 (the map's own, the thesis' rule) or
    # s > 1 (a variant: the partial maps pooled s x s, so the 160-cell window spans s times the
    # metres, and its distribution spread back over the map's cells)
    sampler_scale: int = 1
    # what a metre through an unknown cell costs in the edge weights against one through a known
    # free cell (PRM's unknown_weight): 1, the thesis' rule, or above 1 (a variant for either
    # planner: still optimistic, but a route already seen free wins over an equal one through
    # unknown space)
    unknown_weight: float = 1.0
    reuse_roadmap: bool = True  # uniform sampler: keep the roadmap across replans
    # The loop's compiled steps see the map padded at the bottom and right to its size bucket:
    # a side below this many cells to the next of 32, 48, 64, 96, 128, 192, ..., a longer one to a
    # multiple of it (the padding: known occupied, sensed as walls, no sampling mass), so maps
    # of different shapes in one bucket (and the same origin, resolution and radius) share one
    # compile; the trial's paths, maps and distributions are those of the unpadded map (long
    # query edges and plan segments checked over the bucket's reach). 1: no
    # padding. A pooled sampler (sampler_scale > 1) sees the unpadded map.
    shape_bucket: int = 256
    sensor: SensorConfig = SensorConfig()
    max_context_distance: float = 20.0


@dataclasses.dataclass
class NavResult:
    """Outcome of one trial. path: (T, 2) world polyline travelled (start first: the position after
    each step, plus the plan corners passed within a step); cost: metres travelled (its length); success; reason: 'goal', 'no_plan', 'max_steps' or 'collision' (the robot ended up in a cell its map knows to be occupied); steps; plans (roadmaps built);
    final_state: the partial maps at the end; last_distribution: (H, W) or None; grown: roadmap
    growths after failed searches; searches: roadmap queries (replans); blocked_replans /
    periodic_replans: replans because the rest of the plan crossed a known obstacle / because
    ``replan_every`` steps had passed on a clear plan (the others are the first plan and the
    replans after a first leg that the turn showed blocked);
    distributions: (step, xy, (160, 160) window distribution, (2,) window centre cell, in the
    sampler's cells: ``NavConfig.sampler_scale`` map cells wide) at each
    of the first ``keep_distributions`` LSD replans (``Trial(keep_distributions=...)``)"""

    path: np.ndarray
    cost: float
    success: bool
    reason: str
    steps: int
    plans: int
    final_state: MapState
    last_distribution: np.ndarray | None = None
    grown: int = 0
    searches: int = 0
    distributions: list = dataclasses.field(default_factory=list)
    blocked_replans: int = 0
    periodic_replans: int = 0


def _check_sampler_cells(sampler, resolution: float, scale: int) -> None:
    """Refuse a learned sampler on a map whose cells are not the ones it was trained on.

    A sampler that says its training cell size (``sampler.cell_size``, as
    :class:`jaxsem.lsd.LSDSampler` does) is checked when ``NavConfig.sampler_scale`` is 1: its
    fixed window would then cover other metres than in training (on a 0.05 m map, half the
    building), and its distributions lose the structure they learnt without any error. A
    ValueError rather than a silent resample: the planner plans, checks collisions and measures
    paths on the map it is given, and the two fixes (resample the map, or let the sampler see
    coarser cells with ``sampler_scale``) are the user's choice. An explicit ``sampler_scale`` > 1
    is taken as the user's choice of the sampler's cells (a variant).
    """
    cell = getattr(sampler, "cell_size", None)
    if cell is None or scale != 1 or math.isclose(resolution, float(cell), rel_tol=1e-3):
        return
    ratio = float(cell) / resolution
    hint = f" or NavConfig(sampler_scale={round(ratio)})" if ratio > 1.5 and abs(ratio - round(ratio)) < 1e-3 else ""
    raise ValueError(
        f"sampler: the network was trained on {float(cell):g} m cells, but world.resolution is {resolution:g} m; "
        f"resample the map (planning.load_map(..., cell_size={float(cell):g}))"
        f"{hint}"
    )


class Trial:
    """One navigation trial, advanced a step at a time (:func:`navigate` runs it to the end; the
    expert data generator interleaves its own queries between steps).

    world: anything with ``occupancy`` (H, W) bool, ``semantic`` (H, W) int8, ``indoor`` (H, W)
    bool, ``origin`` (2,), ``resolution`` (e.g. a :class:`~jaxsem.planning.Building`).

    ``state`` (the partial maps) is a new :class:`MapState` after every look; from the second
    look on, the sensing step updates the trial's own arrays in place (the previous ones are
    given up: copying millions of cells at every step cost more than sensing), so read the
    current ``trial.state`` rather than one kept from an earlier step (``np.array`` of it is a
    copy that stays). A ``state`` given to the trial is not changed.
    """

    def __init__(
        self,
        world,
        start,
        goal,
        key,
        config: NavConfig = NavConfig(),
        sampler: Callable | None = None,
        yaw0: float = 0.0,
        goal_outdoors: bool | None = None,
        state: MapState | None = None,
        keep_distributions: int = 0,
    ):
        occ = check_grid("world.occupancy", world.occupancy, "bool")
        sem = check_grid("world.semantic", world.semantic, "int", shape=occ.shape)
        self.world = world
        self.origin = np.asarray(world.origin, np.float64)
        self.resolution = _check_resolution(world.resolution)
        self.grid = Q.Grid.host(self.origin, self.resolution, occ.shape)
        self.start = check_point("start", start, occ, self.grid)
        self.goal = check_point("goal", goal, occ, self.grid)
        if goal_outdoors is None:
            gr, gc = Q.world_to_cell(self.goal, self.origin, self.resolution, xp=np)
            goal_outdoors = getattr(world, "outside_is_outdoors", True) and not bool(np.asarray(world.indoor)[gr, gc])
        self.goal_outdoors = bool(goal_outdoors)
        if (
            config.n_samples < 1
            or config.max_steps < 1
            or not config.step_length > 0
            or config.max_growth < 0
            or config.growth not in ("sampler", "uniform")
            or not config.learned_radius_factor >= 1.0
            or not (
                config.outside_mass is None
                or (len(config.outside_mass) == 2 and all(0.0 <= float(q) < 1.0 for q in config.outside_mass))
            )
            or not 0.0 < config.unknown_weight < math.inf
            or not (isinstance(config.sampler_scale, int) and config.sampler_scale >= 1)
            or not (isinstance(config.shape_bucket, int) and config.shape_bucket >= 1)
        ):
            raise ValueError(
                f"config: n_samples, max_steps >= 1, step_length > 0, max_growth >= 0, growth "
                f"'sampler' or 'uniform', learned_radius_factor >= 1, outside_mass None or two "
                f"shares in [0, 1), a finite unknown_weight > 0, an int sampler_scale >= 1 and an int "
                f"shape_bucket >= 1 expected, got {config}"
            )
        _check_sampler_cells(sampler, self.resolution, config.sampler_scale)
        self.config = config
        self.sampler = sampler
        weight = config.edge_weight or ("euclidean" if sampler is None else "neglogp")
        if weight not in ("euclidean", "neglogp") or (weight == "neglogp" and sampler is None):
            raise ValueError(f"config.edge_weight: {weight!r} not usable with sampler={sampler!r}")
        self.weight = weight
        # The compiled steps run on the map padded to its size bucket (NavConfig.shape_bucket).
        self.shape = (int(occ.shape[0]), int(occ.shape[1]))
        bucket = config.shape_bucket if config.sampler_scale == 1 else 1
        self._shape_p = bucket_shape(self.shape, bucket)
        self._pad = self._shape_p != self.shape
        self._grid_p = Q.Grid.host(self.origin, self.resolution, self._shape_p)
        self._on_map = np.asarray(self.shape, np.int32)
        # Long query edges and plan segments are sampled over the bucket's reach, not the map's:
        # the sample counts are static, so maps of one bucket share those programs too (a longer
        # reach only samples the same edges more densely).
        self._reach = query_reach(self._shape_p, self.resolution)
        self._occ_j = _padded(occ, self._shape_p, True)
        self._sem_j = _padded(np.asarray(sem, np.int8), self._shape_p, NONE)
        self._grid_s = static_grid(self._grid_p)
        self._sense_sizes = _sense_sizes(self.grid, config.sensor)
        self.key = key
        self.xy = self.start.copy()
        self.yaw = float(yaw0)
        if state is None and self._pad:  # built on the host (see _padded)
            unknown = _padded(np.full(occ.shape, UNKNOWN, np.int8), self._shape_p, OCCUPIED)
            self._state = MapState(unknown, jax.device_put(np.full(self._shape_p, NONE, np.int8)))
        else:
            state = state if state is not None else empty_map_state(occ.shape)
            self._state = MapState(
                _padded(state.occupancy, self._shape_p, OCCUPIED), _padded(state.semantic, self._shape_p, NONE)
            )
        self.path = [self.xy.copy()]
        self.cost = 0.0
        self.steps = 0
        self.plans = 0
        self.plan: np.ndarray | None = None  # remaining waypoints, current position first
        self.since_plan = 0
        self.done = False
        self.success = False
        self.reason = ""
        self._last_distribution = None
        self.grown = 0
        self.searches = 0
        self.blocked_replans = 0
        self.periodic_replans = 0
        self.keep_distributions = int(keep_distributions)
        self.distributions: list = []
        self.prm: PRM | None = None
        self.radius = self.connection_radius(config, occ.shape, self.resolution, sampler is not None)
        self._owns_state = False
        self._sense()

    @property
    def state(self) -> MapState:
        """The partial maps now (the map's shape; a view of the trial's own arrays when the map
        needs no padding, else a copy)."""
        st = self._state
        if not self._pad:
            return st
        return MapState(_unpadded(st.occupancy, self.shape), _unpadded(st.semantic, self.shape))

    @state.setter
    def state(self, value: MapState) -> None:
        # The trial's sensing updates its own arrays in place: a state set from outside is
        # copied by the next look instead.
        self._state = MapState(
            _padded(value.occupancy, self._shape_p, OCCUPIED), _padded(value.semantic, self._shape_p, NONE)
        )
        self._owns_state = False

    @property
    def last_distribution(self):
        """The latest replan's (H, W) sampling distribution over the map (None before an LSD
        replan)."""
        d = self._last_distribution
        if isinstance(d, LocalDistribution):
            d = _full_jit(d, self._shape_p)
        return d if d is None or not self._pad else _unpadded(d, self.shape)

    @staticmethod
    def connection_radius(config: NavConfig, shape, resolution: float, learned: bool) -> float:
        """The roadmap's connection radius (m): ``config.radius`` when set, else
        :func:`~jaxsem.planning._roadmap.default_radius` of ``n_samples`` (3 x the mean spacing of uniform
        samples, 6 m on the test buildings at N = 500), times ``learned_radius_factor`` for a
        learned sampler, rounded up to 0.5 m. Why: the window keeps most of the samples and the
        rest of the map (where an outdoor goal lies) only the window's minimum, 5-15 % of them at
        a spacing of 5-8 m, which a 6 m radius leaves in islands; the goal's component was cut
        off from the robot's in all 10 Inside-Outside 'no plan' failures examined
        (``benchmarks/lsd/lsd_diagnose_finding.md``)."""
        if config.radius is not None:
            return float(config.radius)
        r = default_radius(config.n_samples, shape, resolution)
        if learned:
            r = math.ceil(2.0 * r * float(config.learned_radius_factor)) / 2.0
        return r

    def _sense(self):
        pose = jnp.asarray([self.xy[0], self.xy[1], self.yaw], jnp.result_type(float))
        # The first look writes new maps (the state given may be the caller's); later ones
        # update the trial's own maps in place.
        sense = _sense_in_place if self._owns_state else _sense_jit
        self._owns_state = True
        self._state = sense(
            self._occ_j,
            self._sem_j,
            self._state,
            pose,
            self._grid_s,
            self.config.sensor,
            **self._sense_sizes,
        )

    def local_inputs(self) -> LocalInputs:
        """What the learned sampler sees now (its cells ``config.sampler_scale`` map cells wide;
        ``center_cell`` in those cells)."""
        s = self.config.sampler_scale
        state = self._state if s == 1 else _pooled_state(self._state, s)
        return local_inputs(
            state,
            self.xy,
            self.goal,
            self.goal_outdoors,
            self._grid_p
            if s == 1
            else Q.Grid(
                self.origin,
                np.asarray(self.resolution * s),
                (int(state.occupancy.shape[0]), int(state.occupancy.shape[1])),
            ),
            CROP_SIZE,
            self.config.max_context_distance,
        )

    def _clear(self, points) -> bool:
        # The PRM's own edge check, so a plan it found clear is clear here on the same map (read
        # on the device: no copy of the map).
        return polyline_clear(points, self._state.occupancy, self._grid_p, self.radius, reach=self._reach)

    def _new_prm(self, known) -> PRM:
        cfg = self.config
        return PRM(
            known,
            self._grid_p,
            capacity=cfg.n_samples * (1 + cfg.max_growth),
            k=cfg.k if cfg.k is not None else prm_star_k(cfg.n_samples),
            radius=self.radius,
            weight=self.weight,
            sectors=cfg.sectors,
            unknown_weight=cfg.unknown_weight,
            reach=self._reach,
        )

    def _replan(self) -> bool:
        cfg = self.config
        known = np.asarray(self._state.occupancy)
        dist = None
        if self.sampler is not None:
            inputs = self.local_inputs()
            local = jnp.asarray(self.sampler(inputs))
            if local.size != CROP_SIZE * CROP_SIZE:
                raise ValueError(
                    f"sampler: expected a ({CROP_SIZE}, {CROP_SIZE}) distribution (a leading "
                    f"axis of 1 is fine), got shape {tuple(local.shape)}"
                )
            local = local.reshape(CROP_SIZE, CROP_SIZE)
            q = None if cfg.outside_mass is None else float(cfg.outside_mass[int(self.goal_outdoors)])
            s = cfg.sampler_scale
            if s == 1 and q is None:
                # The thesis' rule read from the window (no grid of the map's millions of cells).
                dist = LocalDistribution.centred(local, inputs.center_cell, self._on_map)
            elif s == 1:
                on_map = self._on_map if self._pad else None
                dist = _embed_jit(local, inputs.center_cell, known.shape, q, on_map)
            else:
                pooled = (-(-known.shape[0] // s), -(-known.shape[1] // s))
                dist = _unpooled(_embed_jit(local, inputs.center_cell, pooled, q), s, known.shape)
            self._last_distribution = dist
            if self.keep_distributions and len(self.distributions) < self.keep_distributions:
                self.distributions.append(
                    (
                        self.steps,
                        self.xy.copy(),
                        np.asarray(local, np.float32),
                        np.asarray(inputs.center_cell),
                    )
                )
        # Reuse only a roadmap of the nominal size: one grown for an earlier failure is not kept
        # (so both planners plan with n_samples until a search fails).
        prm = self.prm
        reuse = prm is not None and self.sampler is None and cfg.reuse_roadmap and prm.count == cfg.n_samples
        if prm is not None and reuse:
            prm.update_map(known)
        else:
            prm = self.prm = self._new_prm(known)
            self.key, sub = jax.random.split(self.key)
            prm.grow(sub, cfg.n_samples, dist)
            self.plans += 1
        res = prm.query(self.xy, self.goal)
        self.searches += 1
        while not res.found:
            if prm.count + cfg.n_samples > prm.capacity:
                if not reuse:
                    return False
                # A reused roadmap at capacity: start a fresh one before giving up.
                reuse = False
                prm = self.prm = self._new_prm(known)
                self.plans += 1
            self.key, sub = jax.random.split(self.key)
            prm.grow(sub, cfg.n_samples, dist, uniform_samples=cfg.growth == "uniform")
            self.grown += 1
            res = prm.query(self.xy, self.goal)
            self.searches += 1
        self.plan = np.asarray(res.points, np.float64)
        self.plan[0] = self.xy
        self.plan[-1] = self.goal
        self.since_plan = 0
        return True

    def _in_known_obstacle(self) -> bool:
        rc = Q.world_to_cell(self.xy, self.origin, self.resolution, xp=np)
        occ = self._state.occupancy  # one cell read on the device (no host view: see _sense)
        if not Q.cell_in_grid(rc, occ.shape, xp=np):
            return False
        return int(_cell_at(occ, np.int32(rc[0]), np.int32(rc[1]))) == OCCUPIED

    def _finish(self, success, reason):
        self.done, self.success, self.reason = True, success, reason

    def step(self) -> bool:
        """Advances one timestep; returns True while the trial is running."""
        if self.done:
            return False
        cfg = self.config
        if np.linalg.norm(self.goal - self.xy) <= cfg.goal_tolerance:
            self._finish(True, "goal")
            return False
        if self.steps >= cfg.max_steps:
            self._finish(False, "max_steps")
            return False
        if self.plan is not None:
            # Face the next waypoint and look before moving (so the move itself is always seen).
            nxt = self.plan[1] if len(self.plan) > 1 else self.goal
            d = nxt - self.xy
            if np.hypot(*d) > 1e-9:
                self.yaw = math.atan2(d[1], d[0])
                self._sense()
        if self._in_known_obstacle():
            # The robot stands in a cell its map now knows to be occupied (it moved through
            # unknown space that was not free), known from an earlier look or from this step's:
            # a collision, which ends the trial (the thesis counts these apart, under 2 % of its
            # trials). Checked after the look, so no roadmap is ever asked to start there.
            self._finish(False, "collision")
            return False
        replan = self.plan is None  # the first plan, or a first leg the turn showed blocked
        if not replan and not self._clear(self.plan):
            replan, self.blocked_replans = True, self.blocked_replans + 1
        elif not replan and self.since_plan >= cfg.replan_every:
            replan, self.periodic_replans = True, self.periodic_replans + 1
        if replan:
            if not self._replan():
                self._finish(False, "no_plan")
                return False
            assert self.plan is not None  # set by a successful _replan()
            d = self.plan[1] - self.xy
            if np.hypot(*d) > 1e-9:
                self.yaw = math.atan2(d[1], d[0])
                self._sense()
                if not self._clear(self.plan[:2]):
                    # The first leg is blocked by what the turn revealed; replan next step.
                    self.plan = None
                    self.steps += 1
                    return True
        # Move step_length along the plan.
        remaining = cfg.step_length
        plan = self.plan
        assert plan is not None  # kept (why == "") or set by the replan above
        while remaining > 1e-12 and len(plan) > 1:
            seg = plan[1] - plan[0]
            L = float(np.hypot(*seg))
            if L <= remaining:
                remaining -= L
                plan = plan[1:]
                if remaining > 1e-12 and len(plan) > 1:
                    self.path.append(plan[0].copy())  # a corner passed within the step
                    # Face the next leg and look before moving along it (it was checked only
                    # against the map of the last look); stop at the corner if it is blocked.
                    d = plan[1] - plan[0]
                    if np.hypot(*d) > 1e-9:
                        self.xy = plan[0].copy()
                        self.yaw = math.atan2(d[1], d[0])
                        self._sense()
                        if not self._clear(plan[:2]):
                            break
            else:
                plan = plan.copy()
                plan[0] = plan[0] + seg * (remaining / L)
                remaining = 0.0
        moved = cfg.step_length - remaining
        self.cost += moved
        self.xy = plan[0].copy()
        self.plan = plan
        self.path.append(self.xy.copy())
        self.steps += 1
        self.since_plan += 1
        return True

    def result(self) -> NavResult:
        last = self.last_distribution
        dist = None if last is None else np.asarray(last)
        return NavResult(
            np.array(self.path),
            float(self.cost),
            self.success,
            self.reason,
            self.steps,
            self.plans,
            self.state,
            dist,
            self.grown,
            self.searches,
            list(self.distributions),
            self.blocked_replans,
            self.periodic_replans,
        )


def navigate(
    world,
    start,
    goal,
    key,
    config: NavConfig = NavConfig(),
    sampler: Callable | None = None,
    yaw0: float = 0.0,
    goal_outdoors: bool | None = None,
) -> NavResult:
    """Runs one online navigation trial from ``start`` to ``goal`` (world (x, y), (2,)).

    world: a :class:`~jaxsem.planning.Building` (or an object with the same map fields); key: a
    JAX PRNG key (roadmap samples); sampler: None (uniform PRM) or a function of
    :class:`LocalInputs` returning (160, 160) probabilities; yaw0: initial heading (radians);
    goal_outdoors: the context flag (default: ``world.indoor`` at the goal says outside, and
    the world's outside is the open air: ``Building.outside_is_outdoors``).
    Returns a :class:`NavResult`.
    """
    trial = Trial(world, start, goal, key, config, sampler, yaw0, goal_outdoors)
    while trial.step():
        pass
    return trial.result()
