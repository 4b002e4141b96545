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
"""

from __future__ import annotations

import dataclasses

import numpy as np

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
FAMILIES = {"train": TRAIN_PARAMS, "test": TEST_PARAMS}


@dataclasses.dataclass(frozen=True)
class Building:
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

    @property
    def shape(self) -> tuple:
        return tuple(self.occupancy.shape)

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


def generate_building(
    seed: int, family: str = "train", resolution: float = DEFAULT_RESOLUTION, params: BuildingParams | None = None
) -> Building:
    """One procedural building of ``family`` ('train' or 'test'), deterministic in ``seed``.

    ``params`` overrides the family's :class:`BuildingParams`. See the module docstring for the
    layout rules and :class:`Building` for the arrays returned.
    """
    if family not in FAMILIES:
        raise ValueError(f"family: expected one of {sorted(FAMILIES)}, got {family!r}")
    if not (isinstance(resolution, (int, float)) and 0.02 <= resolution <= 0.5):
        raise ValueError(f"resolution: expected metres per cell in [0.02, 0.5], got {resolution!r}")
    p = params if params is not None else FAMILIES[family]
    rng = np.random.default_rng([int(seed), p.seed_offset, 0x15D])
    cells = lambda m: max(1, int(round(m / resolution)))

    width, depth = cells(rng.uniform(*p.width)), cells(rng.uniform(*p.depth))
    margin = cells(p.margin)
    H, W = depth + 2 * margin, width + 2 * margin
    region = np.full((H, W), OUTSIDE_REGION, np.int32)
    b0r, b0c, b1r, b1c = margin, margin, margin + depth, margin + width
    region[b0r:b1r, b0c:b1c] = CORRIDOR_REGION

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

    def to_global(rect):
        r0, c0, r1, c1 = rect
        if transpose:
            r0, c0, r1, c1 = c0, r0, c1, r1
        return (r0 + b0r, c0 + b0c, r1 + b0r, c1 + b0c)

    min_room = cells(p.room_size[0] * 0.6)
    max_side = (cells(p.room_size[0]), cells(p.room_size[1]))
    rooms = []
    for blk in blocks:
        rooms += _split(to_global(blk), rng, max_side, min_room)
    for i, (r0, c0, r1, c1) in enumerate(rooms):
        region[r0:r1, c0:c1] = i + 1

    # Walls: every cell with a 4-neighbour in another region (so interior walls are 2 thick).
    wall = np.zeros((H, W), bool)
    d0 = region[1:, :] != region[:-1, :]
    d1 = region[:, 1:] != region[:, :-1]
    wall[1:, :] |= d0
    wall[:-1, :] |= d0
    wall[:, 1:] |= d1
    wall[:, :-1] |= d1
    semantic = np.where(wall, WALL, NONE).astype(np.int8)

    runs = _adjacency_runs(region)
    door_w, clear = cells(p.door_width), max(2, cells(0.3))
    n_regions = len(rooms) + 1
    parent = list(range(n_regions))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def cut_door(a, b):
        cands = [r for r in runs.get((min(a, b), max(a, b)), []) if r[3] - r[2] >= door_w + 2 * clear]
        if not cands:
            return False
        run = cands[int(rng.integers(len(cands)))]
        box = _opening(run, door_w, clear, rng)
        if box is None:  # not reached: the candidates are long enough
            return False
        r0, c0, r1, c1 = box
        wall[r0:r1, c0:c1] = False
        semantic[r0:r1, c0:c1] = DOOR
        parent[find(a)] = find(b)
        return True

    neighbours = {i: set() for i in range(n_regions)}
    for (a, b), rl in runs.items():
        if a >= 0 and any(r[3] - r[2] >= door_w + 2 * clear for r in rl):
            neighbours[a].add(b)
            neighbours[b].add(a)
    for room in rng.permutation(np.arange(1, n_regions)):
        room = int(room)
        if CORRIDOR_REGION in neighbours[room]:
            cut_door(room, CORRIDOR_REGION)
        elif neighbours[room]:
            cut_door(room, int(rng.choice(sorted(neighbours[room]))))
    # Reachability repair: join every component to the corridor's, preferring corridor links.
    for _ in range(2 * n_regions):
        lost = [i for i in range(1, n_regions) if find(i) != find(CORRIDOR_REGION)]
        if not lost:
            break
        progress = False
        for room in lost:
            reached = [n for n in sorted(neighbours[room]) if find(n) == find(CORRIDOR_REGION)]
            if reached and cut_door(room, reached[0]):
                progress = True
        if not progress:
            room = lost[0]
            others = [n for n in sorted(neighbours[room]) if find(n) != find(room)]
            if not others or not cut_door(room, others[0]):
                # A room with no usable wall: merge it into the corridor network (no walls).
                r0, c0, r1, c1 = rooms[room - 1]
                region[r0:r1, c0:c1] = CORRIDOR_REGION
                parent[find(room)] = find(CORRIDOR_REGION)

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
        r0, c0, r1, c1 = box
        wall[r0:r1, c0:c1] = False
        semantic[r0:r1, c0:c1] = DOOR
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
    win_lo, win_hi = cells(p.window_length[0]), cells(p.window_length[1])
    for (a, b), rl in runs.items():
        if a != OUTSIDE_REGION or b == CORRIDOR_REGION:
            continue
        for run in rl:
            if rng.random() > p.window_prob:
                continue
            length = int(rng.integers(win_lo, win_hi + 1))
            box = _opening(run, length, clear + 1, rng)
            if box is None:
                continue
            r0, c0, r1, c1 = box
            keep = semantic[r0:r1, c0:c1] == WALL
            semantic[r0:r1, c0:c1] = np.where(keep, WINDOW, semantic[r0:r1, c0:c1])

    occupancy = wall.copy()
    occupancy[[0, -1], :] = True  # the fence
    occupancy[:, [0, -1]] = True
    semantic[[0, -1], :] = np.where(semantic[[0, -1], :] == NONE, WALL, semantic[[0, -1], :])
    semantic[:, [0, -1]] = np.where(semantic[:, [0, -1]] == NONE, WALL, semantic[:, [0, -1]])
    indoor = np.zeros((H, W), bool)
    indoor[b0r:b1r, b0c:b1c] = True
    origin = np.array([-margin * resolution, -margin * resolution])
    entrance_xy = origin + (np.array(entrance[::-1], np.float64) + 0.5) * resolution
    return Building(
        occupancy=occupancy,
        semantic=semantic,
        indoor=indoor,
        origin=origin,
        resolution=float(resolution),
        entrance=entrance_xy,
        exterior_doors=np.array(ext_doors, np.int64).reshape(-1, 4),
        rooms=np.array([r for i, r in enumerate(rooms) if find(i + 1) == find(0)], np.int64).reshape(-1, 4),
        family=family,
        seed=int(seed),
    )


def building_family(family: str, count: int, start: int = 0, resolution: float = DEFAULT_RESOLUTION):
    """``count`` buildings of ``family`` with seeds ``start, start + 1, ...`` (a list)."""
    return [generate_building(start + i, family, resolution) for i in range(int(count))]
