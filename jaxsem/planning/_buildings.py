"""Procedural buildings for the LSD planning world (numpy; about 10-30 ms per building).

A building is a rectangle of ``width x depth`` metres surrounded by open outdoor space. Inside, a
corridor spine runs along the long axis; when the blocks either side of it are deep, cross
corridors run across the full depth at regular intervals. The remaining rectangles (blocks) are
divided recursively into rooms. Every region (room, the corridor network, the outdoors) owns its
boundary cells as walls, so interior walls are two cells thick. Doors are cut through the wall
between a room and the corridor (or a neighbour room when it has no corridor side), then a repair
pass adds doors until every room is reachable from the corridor. Exterior doors sit where the
corridors meet the exterior wall, with exit signs on the wall beside them (inside face); windows
sit on the exterior walls of rooms. The outermost ring of the map is a fence (occupied) so that
rays and paths never leave the grid.

Train and test families use disjoint seed streams and different size / room parameter ranges.

The ``house`` family (:class:`HouseParams`, :func:`generate_house`) draws homes the size of the
HM3D houses instead (80-280 m^2 footprints, an optional L-shape, a short hall 0.9-1.3 m wide,
rooms 2.2-5.5 m, some pairs of rooms opened into one, 0.8-1.0 m doors, furniture against the walls,
free-standing tables and columns), then takes a navmesh-like margin off the free space (obstacles
grown by one cell, the agent's radius) and adds scan-like noise (ragged obstacle edges, speckles);
free islands cut off by clutter and the inside of furniture are unknown (``Building.known``).
Its seed stream is its own; the train and test families are unchanged by it.

The ``campus`` family (``CAMPUS_PARAMS``) is the train family's layout drawn at the size of the
scanned university buildings: 60-110 m long, 3-6 m corridors, halls up to 12 m, its own seed stream.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import quadrics as Q
from ._grid import DEFAULT_RESOLUTION, DOOR, EXIT_SIGN, NONE, WALL, WINDOW

OUTSIDE_REGION = -1
CORRIDOR_REGION = 0


@dataclasses.dataclass(frozen=True)
class BuildingParams:
    """Ranges (metres) a building family draws from; each ``(lo, hi)`` is sampled uniformly."""

    width: tuple = (32.0, 42.0)
    depth: tuple = (20.0, 28.0)
    margin: float = 6.0  # outdoor space around the building
    corridor_width: tuple = (1.8, 2.4)
    deep_block: float = 9.0  # blocks deeper than this get cross corridors
    cross_spacing: tuple = (12.0, 18.0)
    room_size: tuple = (3.5, 8.0)  # rooms are divided until no side exceeds a draw from this
    door_width: float = 1.0
    window_length: tuple = (1.0, 2.0)
    window_prob: float = 0.8  # chance that an exterior room side gets a window
    n_exterior_doors: tuple = (2, 3)  # inclusive range, at corridor ends
    seed_offset: int = 0  # separates the seed streams of the families


TRAIN_PARAMS = BuildingParams(seed_offset=0)
TEST_PARAMS = BuildingParams(
    width=(38.0, 48.0),
    depth=(24.0, 32.0),
    corridor_width=(2.0, 2.8),
    cross_spacing=(14.0, 20.0),
    room_size=(4.0, 9.5),
    seed_offset=1_000_003,
)
#: Long university buildings like the scanned Malaga campus: 60-110 m long,
#: a 3-6 m corridor spine, cross corridors every 20-40 m, rooms up to 12 m (halls) and a wide
#: outside; the campus' corridors are 3-6 m wide where the train family's are 1.8-2.4 m.
CAMPUS_PARAMS = BuildingParams(
    width=(60.0, 110.0),
    depth=(26.0, 44.0),
    margin=8.0,
    corridor_width=(3.0, 6.0),
    cross_spacing=(20.0, 40.0),
    room_size=(3.5, 12.0),
    n_exterior_doors=(2, 4),
    seed_offset=3_000_017,
)


@dataclasses.dataclass(frozen=True)
class HouseParams:
    """Ranges (metres) of the ``house`` family (:func:`generate_house`); ``(lo, hi)`` uniform."""

    width: tuple = (10.0, 20.0)
    depth: tuple = (8.0, 14.0)
    l_shape_prob: float = 0.5  # chance that a corner rectangle is cut off the footprint
    l_cut: tuple = (0.25, 0.45)  # share of each side the cut corner takes
    margin: float = 4.0  # outdoor yard around the house
    hall_width: tuple = (0.9, 1.3)
    hall_length: tuple = (0.35, 0.7)  # share of the long side
    room_size: tuple = (3.0, 6.5)
    open_plan_prob: float = 0.4  # chance per pair of neighbour rooms of a wide opening instead of a door
    open_width: tuple = (1.6, 3.2)
    door_width: tuple = (0.8, 1.0)
    furniture_per_m2: tuple = (0.15, 0.4)
    furniture_size: tuple = (0.4, 2.0)  # long side; the short side is 0.4-1.0 m
    column_prob: float = 0.15  # share of pieces that are 0.3-0.5 m columns / plants / chairs
    yard_clutter: tuple = (0, 6)  # inclusive range of obstacles (cars, trees) in the yard
    erode: int = 1  # cells taken off the free space (navmesh: the agent's radius)
    ragged_prob: float = 0.12  # chance per obstacle-edge cell of growing one more cell
    speckle_prob: float = 0.002  # chance per free cell of a one-cell obstacle (scan noise)
    window_prob: float = 0.7
    n_exterior_doors: tuple = (1, 2)
    seed_offset: int = 2_000_029


HOUSE_PARAMS = HouseParams()
FAMILIES = {"train": TRAIN_PARAMS, "test": TEST_PARAMS, "house": HOUSE_PARAMS, "campus": CAMPUS_PARAMS}


class GridMap:
    """What every map of the planner shares: an ``occupancy`` (H, W) array on a grid of
    ``origin`` (2,) and ``resolution`` (the fields of its dataclass), seen as ``shape`` and as the
    core's :class:`jaxsem.quadrics.Grid`."""

    occupancy: np.ndarray
    origin: np.ndarray
    resolution: float

    @property
    def shape(self) -> tuple:
        return tuple(self.occupancy.shape)

    @property
    def grid(self) -> Q.Grid:
        """The map's :class:`jaxsem.quadrics.Grid` (origin, resolution, shape), its leaves the
        map's own float64 numpy values (host readers convert exactly; under ``jit`` they become
        the tracer dtype as any numpy argument does)."""
        return Q.Grid.host(self.origin, self.resolution, self.shape)


@dataclasses.dataclass(frozen=True)
class Building(GridMap):
    """A generated building on a grid (numpy arrays; ``[row, col] = [y, x]``).

    occupancy: (H, W) bool, True where a robot cannot be (walls, windows, exit-sign walls, fence).
    semantic:  (H, W) int8 class grid: 0 none, 1 wall, 2 door (free), 3 window, 4 exit sign.
    indoor:    (H, W) bool, True inside the building footprint (walls included).
    origin:    (2,) world (x, y) of the corner of cell [0, 0]; resolution: metres per cell.
    entrance:  (2,) world (x, y) of a free outdoor point just outside the first exterior door
               (NaN when unknown, e.g. a scanned map).
    exterior_doors: (D, 4) int cell boxes [r0, c0, r1, c1) of the exterior door openings.
    rooms: (R, 4) int cell rectangles [r0, c0, r1, c1) of the rooms (corridors excluded).
    family, seed: how it was made ('scanned' and -1 for a map read from a file,
    :func:`~jaxsem.planning.load_map`; a generated building's seed seeds its trials' streams).
    known: (H, W) bool or None: the cells a scan observed (None: all of them). A scanned map's
        unknown cells are blocked in ``occupancy`` and marked here.
    outside_is_outdoors: False when ``~indoor`` is not the open air but a stand-in for it (a
        scanned map with no outside of its own, whose largest open hall or room takes the
        Inside-Outside goals, :func:`~jaxsem.planning.grid_to_building`). ``indoor`` still
        decides the task pools; this decides the LSD network's ``goal_outdoors`` flag, which
        says where the goal is, not which pool it came from: a goal in a hall is indoors.

    Only the first five fields are needed; the rest describe how a generated building was made.
    """

    occupancy: np.ndarray
    semantic: np.ndarray
    indoor: np.ndarray
    origin: np.ndarray
    resolution: float
    entrance: np.ndarray = dataclasses.field(default_factory=lambda: np.full(2, np.nan))
    exterior_doors: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 4), np.int64))
    rooms: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 4), np.int64))
    family: str = "scanned"
    seed: int = -1
    known: np.ndarray | None = None
    outside_is_outdoors: bool = True

    def cell_center(self, rc) -> np.ndarray:
        """World (x, y) (..., 2) of the centre of cell (row, col) (..., 2) (numpy, host side;
        :func:`~jaxsem.planning.cell_to_world` is the jitted form)."""
        return Q.cell_to_world(rc, self.origin, self.resolution, xp=np)

    def free_cells(self, indoor: bool | None = None) -> np.ndarray:
        """(M, 2) int cells that are free; ``indoor`` True/False restricts to inside/outside."""
        mask = ~self.occupancy
        if indoor is not None:
            mask &= self.indoor if indoor else ~self.indoor
        return np.argwhere(mask)


def _split(rect, rng, max_side, min_side):
    """Recursive division of a rectangle [r0, c0, r1, c1) in cells into rooms."""
    r0, c0, r1, c1 = rect
    h, w = r1 - r0, c1 - c0
    limit = rng.uniform(*max_side)
    if max(h, w) <= limit or max(h, w) < 2 * min_side:
        return [rect]
    if h >= w:
        cut = int(rng.integers(r0 + min_side, r1 - min_side + 1))
        return _split((r0, c0, cut, c1), rng, max_side, min_side) + _split((cut, c0, r1, c1), rng, max_side, min_side)
    cut = int(rng.integers(c0 + min_side, c1 - min_side + 1))
    return _split((r0, c0, r1, cut), rng, max_side, min_side) + _split((r0, cut, r1, c1), rng, max_side, min_side)


def _divide(blocks, transpose: bool, corner, rng, p, cells, skip_empty: bool = False) -> list:
    """Rooms (r0, c0, r1, c1) of the grid: each block, given in a local frame (rows and columns
    swapped when ``transpose``, offset by the footprint's ``corner``), split by :func:`_split`
    into rooms of ``p.room_size`` (m); ``skip_empty`` passes over blocks with no cells."""
    min_room = cells(p.room_size[0] * 0.6)
    max_side = (cells(p.room_size[0]), cells(p.room_size[1]))
    rooms = []
    for r0, c0, r1, c1 in blocks:
        if transpose:
            r0, c0, r1, c1 = c0, r0, c1, r1
        g = (r0 + corner[0], c0 + corner[1], r1 + corner[0], c1 + corner[1])
        if not skip_empty or (g[2] > g[0] and g[3] > g[1]):
            rooms += _split(g, rng, max_side, min_room)
    return rooms


def _adjacency_runs(region):
    """{(a, b): list of (axis, fixed, lo, hi)} shared boundaries between regions a < b.

    axis 0: horizontal boundary between rows ``fixed`` and ``fixed + 1`` over columns [lo, hi);
    axis 1: vertical boundary between columns ``fixed`` and ``fixed + 1`` over rows [lo, hi).
    """
    runs: dict = {}
    for axis in (0, 1):
        a = region[:-1, :] if axis == 0 else region[:, :-1]
        b = region[1:, :] if axis == 0 else region[:, 1:]
        diff = a != b
        idx = np.argwhere(diff)
        if len(idx) == 0:
            continue
        fixed = idx[:, 0] if axis == 0 else idx[:, 1]
        along = idx[:, 1] if axis == 0 else idx[:, 0]
        ra, rb = a[diff], b[diff]
        lo_id, hi_id = np.minimum(ra, rb), np.maximum(ra, rb)
        order = np.lexsort((along, fixed, hi_id, lo_id))
        fixed, along, lo_id, hi_id = fixed[order], along[order], lo_id[order], hi_id[order]
        # Break into contiguous runs of the same (pair, fixed) with consecutive `along`.
        brk = np.ones(len(along), bool)
        brk[1:] = (
            (lo_id[1:] != lo_id[:-1])
            | (hi_id[1:] != hi_id[:-1])
            | (fixed[1:] != fixed[:-1])
            | (along[1:] != along[:-1] + 1)
        )
        starts = np.flatnonzero(brk)
        ends = np.append(starts[1:], len(along))
        for s, e in zip(starts, ends):
            key = (int(lo_id[s]), int(hi_id[s]))
            runs.setdefault(key, []).append((axis, int(fixed[s]), int(along[s]), int(along[e - 1]) + 1))
    return runs


def _opening(run, width, clearance, rng):
    """Cell box [r0, c0, r1, c1) cutting through the 2-cell wall of ``run``, or None if too short."""
    axis, fixed, lo, hi = run
    if hi - lo < width + 2 * clearance:
        return None
    start = int(rng.integers(lo + clearance, hi - clearance - width + 1))
    if axis == 0:
        return (fixed, start, fixed + 2, start + width)
    return (start, fixed, start + width, fixed + 2)


class _Openings:
    """The walls of a region grid and the openings cut through them, for both generators.

    Every cell with a 4-neighbour in another region is wall (so interior walls are two cells
    thick). Doors go through a run of wall two regions share, ``clear`` cells off its ends; a
    union-find over the regions records which are joined, so that a repair pass can add doors
    until every room reaches the corridor. All random draws come from ``rng`` in the order the
    generators have always made them (their outputs are pinned).
    """

    def __init__(self, region, n_regions: int, clear: int, rng):
        wall = np.zeros(region.shape, bool)
        d0 = region[1:, :] != region[:-1, :]
        d1 = region[:, 1:] != region[:, :-1]
        wall[1:, :] |= d0
        wall[:-1, :] |= d0
        wall[:, 1:] |= d1
        wall[:, :-1] |= d1
        self.wall = wall
        self.semantic = np.where(wall, WALL, NONE).astype(np.int8)
        self.door = np.zeros(region.shape, bool)  # every cell opened (doors and open-plan gaps)
        self.runs = _adjacency_runs(region)
        self.n_regions, self.clear, self.rng = n_regions, clear, rng
        self.parent = list(range(n_regions))

    def find(self, i: int) -> int:
        parent = self.parent
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def open(self, box, label=DOOR):
        """Clear the wall in cell box ``box`` and mark it ``label`` in the semantic grid."""
        r0, c0, r1, c1 = box
        self.wall[r0:r1, c0:c1] = False
        self.semantic[r0:r1, c0:c1] = label
        self.door[r0:r1, c0:c1] = True

    def cut(self, a: int, b: int, width: int, label=DOOR) -> bool:
        """A ``width``-cell opening on a random run of the wall between regions a and b; False if
        no run is long enough."""
        cands = [r for r in self.runs.get((min(a, b), max(a, b)), []) if r[3] - r[2] >= width + 2 * self.clear]
        if not cands:
            return False
        box = _opening(cands[int(self.rng.integers(len(cands)))], width, self.clear, self.rng)
        if box is None:  # not reached: the candidates are long enough
            return False
        self.open(box, label)
        self.parent[self.find(a)] = self.find(b)
        return True

    def neighbours(self, min_width: int) -> dict:
        """{region: set of regions} sharing a wall run long enough for a ``min_width`` door."""
        out: dict = {i: set() for i in range(self.n_regions)}
        for (a, b), rl in self.runs.items():
            if a >= 0 and any(r[3] - r[2] >= min_width + 2 * self.clear for r in rl):
                out[a].add(b)
                out[b].add(a)
        return out

    def link_rooms(self, neighbours: dict, width, skip=None):
        """One door per room in a random order, to the corridor where they touch, else to a
        random neighbour; ``width()`` draws each door's width (after the neighbour), ``skip(room)``
        passes a room over."""
        for room in self.rng.permutation(np.arange(1, self.n_regions)):
            room = int(room)
            if skip is not None and skip(room):
                continue
            if CORRIDOR_REGION in neighbours[room]:
                self.cut(room, CORRIDOR_REGION, width())
            elif neighbours[room]:
                self.cut(room, int(self.rng.choice(sorted(neighbours[room]))), width())

    def repair(self, neighbours: dict, width: int) -> list:
        """Doors until every room reaches the corridor, preferring links to its component; a room
        with no usable wall is joined to the corridor's component without one. Returns those rooms."""
        sealed = []
        corridor = CORRIDOR_REGION
        for _ in range(2 * self.n_regions):
            lost = [i for i in range(1, self.n_regions) if self.find(i) != self.find(corridor)]
            if not lost:
                break
            progress = False
            for room in lost:
                reached = [n for n in sorted(neighbours[room]) if self.find(n) == self.find(corridor)]
                if reached and self.cut(room, reached[0], width):
                    progress = True
            if not progress:
                room = lost[0]
                others = [n for n in sorted(neighbours[room]) if self.find(n) != self.find(room)]
                if not others or not self.cut(room, others[0], width):
                    self.parent[self.find(room)] = self.find(corridor)
                    sealed.append(room)
        return sealed

    def building(
        self, occupancy, semantic, indoor, margin, resolution, entrance, ext_doors, rooms, family, seed, known=None
    ) -> Building:
        """The :class:`Building` of these grids: origin ``margin`` cells outside the footprint's
        corner, the entrance cell in metres, and the rooms the corridor reaches."""
        origin = np.array([-margin * resolution, -margin * resolution])
        reached = [r for i, r in enumerate(rooms) if self.find(i + 1) == self.find(CORRIDOR_REGION)]
        return Building(
            occupancy=occupancy,
            semantic=semantic,
            indoor=indoor,
            origin=origin,
            resolution=float(resolution),
            entrance=Q.cell_to_world(np.array(entrance), origin, resolution, xp=np),
            exterior_doors=np.array(ext_doors, np.int64).reshape(-1, 4),
            rooms=np.array(reached, np.int64).reshape(-1, 4),
            family=family,
            seed=int(seed),
            known=known,
        )

    def windows(self, prob: float, length: tuple, clearance: int):
        """Windows on the rooms' exterior wall runs (each run with probability ``prob``, its
        length drawn from ``length`` cells, inclusive): WINDOW over the wall cells of both layers."""
        for (a, b), rl in self.runs.items():
            if a != OUTSIDE_REGION or b == CORRIDOR_REGION:
                continue
            for run in rl:
                if self.rng.random() > prob:
                    continue
                box = _opening(run, int(self.rng.integers(length[0], length[1] + 1)), clearance, self.rng)
                if box is None:
                    continue
                r0, c0, r1, c1 = box
                keep = self.semantic[r0:r1, c0:c1] == WALL
                self.semantic[r0:r1, c0:c1] = np.where(keep, WINDOW, self.semantic[r0:r1, c0:c1])


def _footprint(rng, p, resolution: float):
    """The footprint every family draws first, in this order from ``rng``: width and depth
    within ``p.width`` / ``p.depth`` (m), a ``p.margin`` of outside around it. Returns the
    metres-to-cells rounding, width, depth and margin in cells, the region grid (outside, and the
    footprint as corridor) and the footprint's (r0, c0, r1, c1)."""
    cells = lambda m: max(1, int(round(m / resolution)))
    width, depth = cells(rng.uniform(*p.width)), cells(rng.uniform(*p.depth))
    margin = cells(p.margin)
    region = np.full((depth + 2 * margin, width + 2 * margin), OUTSIDE_REGION, np.int32)
    rect = (margin, margin, margin + depth, margin + width)
    region[rect[0] : rect[2], rect[1] : rect[3]] = CORRIDOR_REGION
    return cells, width, depth, margin, region, rect


def generate_building(
    seed: int, family: str = "train", resolution: float = DEFAULT_RESOLUTION, params: BuildingParams | None = None
) -> Building:
    """One procedural building of ``family`` ('train', 'test', 'house' or 'campus'), deterministic in ``seed``.

    ``params`` overrides the family's :class:`BuildingParams` (:class:`HouseParams`: a house). See the module docstring for the
    layout rules and :class:`Building` for the arrays returned.
    """
    if family not in FAMILIES:
        raise ValueError(f"family: expected one of {sorted(FAMILIES)}, got {family!r}")
    if not (isinstance(resolution, (int, float)) and 0.02 <= resolution <= 0.5):
        raise ValueError(f"resolution: expected metres per cell in [0.02, 0.5], got {resolution!r}")
    p = params if params is not None else FAMILIES[family]
    if isinstance(p, HouseParams):
        return generate_house(seed, resolution, p, family)
    if not isinstance(p, BuildingParams):
        raise ValueError(f"params: expected BuildingParams or HouseParams, got {type(p).__name__}")
    rng = np.random.default_rng([int(seed), p.seed_offset, 0x15D])
    cells, width, depth, margin, region, (b0r, b0c, b1r, b1c) = _footprint(rng, p, resolution)
    H, W = region.shape

    # Corridor spine along the long axis; work in a frame where the spine is horizontal.
    transpose = depth > width
    L, D = (depth, width) if transpose else (width, depth)
    cw = cells(rng.uniform(*p.corridor_width))
    spine_lo = (D - cw) // 2 + int(rng.integers(-cells(1.5), cells(1.5) + 1))
    spine = (spine_lo, spine_lo + cw)  # rows in the local frame
    block_depth = max(spine[0], D - spine[1])
    cross_cols = []
    if block_depth > cells(p.deep_block):
        pos = cells(rng.uniform(*p.cross_spacing))
        while pos + cw < L - cells(4.0):
            cross_cols.append(pos)
            pos += cw + cells(rng.uniform(*p.cross_spacing))
    # Blocks in the local frame: split by the spine (rows) and cross corridors (cols).
    col_edges = [0]
    for c in cross_cols:
        col_edges += [c, c + cw]
    col_edges.append(L)
    col_spans = [(col_edges[i], col_edges[i + 1]) for i in range(0, len(col_edges), 2)]
    blocks = []
    for cs in col_spans:
        blocks.append((0, cs[0], spine[0], cs[1]))
        blocks.append((spine[1], cs[0], D, cs[1]))

    rooms = _divide(blocks, transpose, (b0r, b0c), rng, p, cells)
    for i, (r0, c0, r1, c1) in enumerate(rooms):
        region[r0:r1, c0:c1] = i + 1

    # Walls (two cells thick between regions), a door per room, then doors until all are reached.
    door_w, clear = cells(p.door_width), max(2, cells(0.3))
    n_regions = len(rooms) + 1
    walls = _Openings(region, n_regions, clear, rng)
    wall, semantic, runs = walls.wall, walls.semantic, walls.runs
    neighbours = walls.neighbours(door_w)
    walls.link_rooms(neighbours, lambda: door_w)
    for room in walls.repair(neighbours, door_w):
        # A room with no usable wall: merged into the corridor network (no walls).
        r0, c0, r1, c1 = rooms[room - 1]
        region[r0:r1, c0:c1] = CORRIDOR_REGION

    # Exterior doors at corridor ends, exit signs on the inside face beside them.
    ext_runs = [r for r in runs.get((OUTSIDE_REGION, CORRIDOR_REGION), []) if r[3] - r[2] >= door_w + 6]
    rng.shuffle(ext_runs)
    n_ext = int(rng.integers(p.n_exterior_doors[0], p.n_exterior_doors[1] + 1))
    ext_doors, entrance = [], None
    for run in ext_runs[: max(1, n_ext)]:
        axis, fixed, lo, hi = run
        box = _opening((axis, fixed, lo, hi), door_w, 3, rng)
        if box is None:  # not reached: ext_runs are long enough
            continue
        walls.open(box)
        r0, c0, r1, c1 = box
        ext_doors.append(box)
        # Which of the two wall layers faces the corridor (inside the footprint)?
        if axis == 0:
            inner = r0 if region[r0, c0] == CORRIDOR_REGION else r0 + 1
            outer = r0 + 1 if inner == r0 else r0
            side = [c0 - 2, c0 - 1] if rng.random() < 0.5 else [c1, c1 + 1]
            semantic[inner, side] = EXIT_SIGN
            step = 1 if outer > inner else -1
            out_cell = (outer + 2 * step, (c0 + c1) // 2)
        else:
            inner = c0 if region[r0, c0] == CORRIDOR_REGION else c0 + 1
            outer = c0 + 1 if inner == c0 else c0
            side = [r0 - 2, r0 - 1] if rng.random() < 0.5 else [r1, r1 + 1]
            semantic[side, inner] = EXIT_SIGN
            step = 1 if outer > inner else -1
            out_cell = ((r0 + r1) // 2, outer + 2 * step)
        if entrance is None:
            entrance = out_cell
    if entrance is None:  # pragma: no cover - every spine reaches the exterior wall
        raise RuntimeError(f"building seed {seed}: no corridor reaches the exterior wall")

    # Windows on the exterior walls of rooms (both wall layers).
    walls.windows(p.window_prob, (cells(p.window_length[0]), cells(p.window_length[1])), clear + 1)

    occupancy = wall.copy()
    occupancy[[0, -1], :] = True  # the fence
    occupancy[:, [0, -1]] = True
    semantic[[0, -1], :] = np.where(semantic[[0, -1], :] == NONE, WALL, semantic[[0, -1], :])
    semantic[:, [0, -1]] = np.where(semantic[:, [0, -1]] == NONE, WALL, semantic[:, [0, -1]])
    indoor = np.zeros((H, W), bool)
    indoor[b0r:b1r, b0c:b1c] = True
    return walls.building(occupancy, semantic, indoor, margin, resolution, entrance, ext_doors, rooms, family, seed)


def _outer_cell(region, box, axis, rng, semantic=None):
    """The free outdoor cell two cells beyond an exterior opening ``box`` (see generate_building)."""
    r0, c0, r1, c1 = box
    if axis == 0:
        inner = r0 if region[r0, c0] != OUTSIDE_REGION else r0 + 1
        outer = r0 + 1 if inner == r0 else r0
        return (outer + 2 * (1 if outer > inner else -1), (c0 + c1) // 2)
    inner = c0 if region[r0, c0] != OUTSIDE_REGION else c0 + 1
    outer = c0 + 1 if inner == c0 else c0
    return ((r0 + r1) // 2, outer + 2 * (1 if outer > inner else -1))


def _label(mask, structure) -> tuple:
    """``(labels, count)`` of scipy's connected components, typed."""
    import scipy.ndimage as ndi  # deferred: scipy is slow to import and only this step needs it

    out = ndi.label(mask, structure)
    return np.asarray(out[0]), int(out[1])  # type: ignore[index]


def generate_house(
    seed: int, resolution: float = DEFAULT_RESOLUTION, params: HouseParams | None = None, family: str = "house"
) -> Building:
    """One house of the ``house`` family (module docstring), deterministic in ``seed``.

    Laid out with the building generator's region rules (two-cell walls owned by both sides,
    doors cut through shared wall runs, a repair pass until every room is reached), then
    furnished (a piece is kept only if the eroded free space stays connected and it keeps 0.7 m
    off every door), eroded by ``params.erode`` cells and roughened. ``Building.known`` is False
    on furniture interiors and on free islands cut off by the noise (both blocked).
    """
    import scipy.ndimage as ndi  # deferred: scipy is slow to import and only this step needs it

    p = params if params is not None else HOUSE_PARAMS
    if not isinstance(p, HouseParams):
        raise ValueError(f"params: expected HouseParams, got {type(p).__name__}")
    if not (isinstance(resolution, (int, float)) and 0.02 <= resolution <= 0.5):
        raise ValueError(f"resolution: expected metres per cell in [0.02, 0.5], got {resolution!r}")
    rng = np.random.default_rng([int(seed), p.seed_offset, 0x4053])
    cells, width, depth, margin, region, (b0r, b0c, b1r, b1c) = _footprint(rng, p, resolution)
    H, W = region.shape
    if rng.random() < p.l_shape_prob:  # cut a corner off: an L-shaped footprint
        ch, cw = int(depth * rng.uniform(*p.l_cut)), int(width * rng.uniform(*p.l_cut))
        corner = int(rng.integers(4))
        rs = slice(b0r, b0r + ch) if corner < 2 else slice(b1r - ch, b1r)
        cs = slice(b0c, b0c + cw) if corner % 2 == 0 else slice(b1c - cw, b1c)
        region[rs, cs] = OUTSIDE_REGION
    footprint = region != OUTSIDE_REGION

    # A short hall along the long axis from one end; the rest is divided into rooms.
    horizontal = width >= depth
    L, D = (width, depth) if horizontal else (depth, width)
    hw, hl = cells(rng.uniform(*p.hall_width)), int(L * rng.uniform(*p.hall_length))
    h0 = (D - hw) // 2 + int(rng.integers(-D // 6, D // 6 + 1))
    from_start = rng.random() < 0.5
    a0, a1 = (0, hl) if from_start else (L - hl, L)
    local_blocks = [(0, a0, h0, a1), (h0 + hw, a0, D, a1)]
    local_blocks.append((0, a1, D, L) if from_start else (0, 0, D, a0))

    rects = _divide(local_blocks, not horizontal, (b0r, b0c), rng, p, cells, skip_empty=True)
    rooms = []
    for r0, c0, r1, c1 in rects:
        sub = footprint[r0:r1, c0:c1]
        if not sub.any():  # all cut off by the L-shape
            continue
        rooms.append((r0, c0, r1, c1))
        region[r0:r1, c0:c1] = np.where(sub, len(rooms), region[r0:r1, c0:c1])

    clear = max(2, cells(0.3))
    n_regions = len(rooms) + 1
    walls = _Openings(region, n_regions, clear, rng)
    wall, semantic, door, runs, find = walls.wall, walls.semantic, walls.door, walls.runs, walls.find
    neighbours = walls.neighbours(cells(p.door_width[0]))
    for a in range(1, n_regions):  # open plan: wide openings between some neighbour rooms
        for b in sorted(n for n in neighbours[a] if n > a):
            if rng.random() < p.open_plan_prob:
                walls.cut(a, b, cells(rng.uniform(*p.open_width)), label=NONE)
    walls.link_rooms(
        neighbours,
        lambda: cells(rng.uniform(*p.door_width)),
        skip=lambda room: find(room) == find(CORRIDOR_REGION) and rng.random() < 0.5,
    )
    walls.repair(neighbours, cells(p.door_width[0]))  # a sealed room's floor becomes unknown below

    # Exterior doors on any exterior wall run (hall or room), windows on rooms' exterior walls.
    ext_runs = [(k, r) for k in runs if k[0] == OUTSIDE_REGION for r in runs[k] if r[3] - r[2] >= cells(1.1) + 6]
    order = rng.permutation(len(ext_runs))
    n_ext = int(rng.integers(p.n_exterior_doors[0], p.n_exterior_doors[1] + 1))
    ext_doors, entrance = [], None
    for i in order[: max(1, n_ext)]:
        run = ext_runs[int(i)][1]
        box = _opening(run, cells(rng.uniform(0.9, 1.1)), 3, rng)
        if box is None:  # not reached: the runs are long enough
            continue
        walls.open(box)
        ext_doors.append(box)
        if entrance is None:
            entrance = _outer_cell(region, box, run[0], rng)
    if entrance is None:  # pragma: no cover - every footprint has a long exterior run
        raise RuntimeError(f"house seed {seed}: no exterior wall long enough for a door")
    walls.windows(p.window_prob, (cells(0.8), cells(1.8)), clear + 1)

    # Furniture and columns; a piece stays only if the eroded free space stays one piece.
    cross = ndi.generate_binary_structure(2, 1)
    occ = wall.copy()
    occ[[0, -1], :] = True
    occ[:, [0, -1]] = True
    furniture = np.zeros((H, W), bool)
    keep_out = ndi.binary_dilation(door, cross, iterations=cells(0.7))

    def n_free_parts(o):
        free = ~np.asarray(ndi.binary_dilation(o, cross, iterations=p.erode), bool) if p.erode else ~o
        return _label(free, cross)[1]

    parts = n_free_parts(occ)
    for rid, (r0, c0, r1, c1) in enumerate(rooms, start=1):
        inner = (region == rid) & ~wall
        area = float(inner.sum()) * resolution**2
        for _ in range(int(round(area * rng.uniform(*p.furniture_per_m2)))):
            if rng.random() < p.column_prob:
                h = w = cells(rng.uniform(0.3, 0.5))
                rr, cc = int(rng.integers(r0, r1)), int(rng.integers(c0, c1))
            else:
                long, short = cells(rng.uniform(*p.furniture_size)), cells(rng.uniform(0.4, 1.0))
                h, w = (long, short) if rng.random() < 0.5 else (short, long)
                side = int(rng.integers(5))  # 0-3: against a wall of the room, 4: free-standing
                rr, cc = int(rng.integers(r0, max(r0 + 1, r1 - h))), int(rng.integers(c0, max(c0 + 1, c1 - w)))
                if side == 0:
                    rr = r0 + 1
                elif side == 1:
                    rr = r1 - 1 - h
                elif side == 2:
                    cc = c0 + 1
                elif side == 3:
                    cc = c1 - 1 - w
            if rr < 0 or cc < 0 or rr + h > H or cc + w > W:
                continue
            box = (slice(rr, rr + h), slice(cc, cc + w))
            if not inner[box].all() or keep_out[box].any():
                continue
            trial = occ.copy()
            trial[box] = True
            if n_free_parts(trial) > parts:
                continue
            occ, furniture[box] = trial, True
    indoor_near = ndi.binary_dilation(footprint, cross, iterations=cells(1.2))
    for _ in range(int(rng.integers(p.yard_clutter[0], p.yard_clutter[1] + 1))):
        h, w = cells(rng.uniform(0.5, 2.5)), cells(rng.uniform(0.5, 2.5))
        rr, cc = int(rng.integers(1, max(2, H - h - 1))), int(rng.integers(1, max(2, W - w - 1)))
        box = (slice(rr, rr + h), slice(cc, cc + w))
        if indoor_near[box].any():
            continue
        trial = occ.copy()
        trial[box] = True
        if n_free_parts(trial) <= parts:
            occ, furniture[box] = trial, True

    # The navmesh margin, then scan-like noise; free islands cut off by it become unknown.
    if p.erode:
        occ = np.asarray(ndi.binary_dilation(occ, cross, iterations=p.erode), bool)
    edge = np.asarray(ndi.binary_dilation(occ, cross), bool) & ~occ
    occ |= edge & (rng.random((H, W)) < p.ragged_prob)
    occ |= ~occ & (rng.random((H, W)) < p.speckle_prob)
    occ[[0, -1], :] = True
    occ[:, [0, -1]] = True
    labels, n_labels = _label(~occ, cross)
    # The free part that reaches the yard and holds the most floor (an exterior door can open
    # into a sealed closet; the noise can close a door).
    floor = np.bincount(labels[footprint], minlength=n_labels + 1)
    yard = np.bincount(labels[~footprint], minlength=n_labels + 1)
    floor[0] = -1
    main = int(np.argmax(np.where(yard > 0, floor, -1)))
    if labels[entrance] != main:
        entrance = tuple(int(v) for v in np.argwhere((labels == main) & ~footprint)[0])
    island = ~occ & (labels != main)
    occ |= island
    known = ~(island | ndi.binary_erosion(furniture, cross))
    semantic = np.where(occ & (semantic == NONE), WALL, semantic).astype(np.int8)
    semantic = np.where(occ & (semantic == DOOR), WALL, semantic).astype(np.int8)
    semantic = np.where(~occ & (semantic == WALL), NONE, semantic).astype(np.int8)

    return walls.building(occ, semantic, footprint, margin, resolution, entrance, ext_doors, rooms, family, seed, known)


def building_family(family: str, count: int, start: int = 0, resolution: float = DEFAULT_RESOLUTION):
    """``count`` buildings of ``family`` with seeds ``start, start + 1, ...`` (a list)."""
    return [generate_building(start + i, family, resolution) for i in range(int(count))]
