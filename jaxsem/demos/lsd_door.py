"""The LSD demo's door step (thesis 5.8): a door that VoluMon found in the rendered building,
put in an object map, and an LSD plan through it.

From the start of the demo's task the robot's camera (:func:`jaxsem.mapping.robot_camera`, 320 x 240,
69.4 degrees) looks around in eight headings of the rendered building
(:class:`jaxsem.mapping.BuildingRenderer`); the largest door box of the segmentation (the stand-in
detector; boxes off the image border) goes with the RGB image through the shipped VoluMon door
model (:func:`jaxsem.volumon.load_pretrained` ``kind="door"``, monocular), whose world ellipsoid
is the only object of a :mod:`jaxsem.mapping` store. Its raster is the semantic map LSD reads
(:func:`jaxsem.mapping.object_map_sampler`), and the robot navigates to a goal two metres behind
that door. The figure shows the camera view with the box and the estimate's outline, and the
top-down map with the true door, the estimated door's footprint and the path.
"""

from __future__ import annotations

import math
import pathlib
import time

import jax
import numpy as np

from .. import mapping, quadrics
from ..mapping import BuildingRenderer, robot_camera, robot_intrinsics
from ..planning import DOOR, NavConfig, navigate, world_to_cell
from ..scripting import atomic_savefig, record_output
from ..volumon import SingleViewEstimator, load_pretrained

WIDTH, HEIGHT = 320, 240


def _find_door(renderer, K, start, yaw0):
    """The largest door box seen from ``start`` in eight headings: (yaw, camera_T_world, box, index)."""
    best = None
    for i in range(8):
        yaw = float(yaw0) + i * math.pi / 4
        T = robot_camera(start, yaw)
        seg = renderer.render(K, T, outputs=("seg",))["seg"]
        det = renderer.detect(seg, (DOOR,), min_area=300, border=4)
        if len(det):
            j = int(np.argmax(det.area))
            if best is None or det.area[j] > best[4]:
                best = (yaw, T, det.box[j], int(det.object_index[j]), int(det.area[j]))
    return best


def _goal_behind(building, door_lo, door_hi, camera_xy):
    """A free point 1.5-3 m behind the door (on the side away from the camera), or None."""
    centre = 0.5 * (door_lo[:2] + door_hi[:2])
    ext = door_hi[:2] - door_lo[:2]
    normal = np.array([0.0, 1.0]) if ext[0] >= ext[1] else np.array([1.0, 0.0])
    if np.dot(centre - camera_xy, normal) < 0:
        normal = -normal
    occ = np.asarray(building.occupancy)
    for d in (2.0, 1.5, 2.5, 3.0):
        xy = centre + d * normal
        r, c = (int(v) for v in np.asarray(world_to_cell(xy, building.origin, building.resolution)))
        if 0 <= r < occ.shape[0] and 0 <= c < occ.shape[1] and not occ[r, c]:
            return xy
    return None


def run_door_plan(out_dir, building, task, lsd_sampler, quick: bool, door_model=None) -> tuple[list, dict]:
    """Find a door with VoluMon, map it, plan through it with ``lsd_sampler`` (a
    :class:`jaxsem.lsd.LSDSampler`); returns (table lines, JSON record)."""
    t0 = time.perf_counter()
    try:
        vm, vv, vc, meta = load_pretrained(door_model, kind="door")
    except ValueError as exc:
        return [f"door step skipped: {exc}"], {"skipped": str(exc)}
    K = robot_intrinsics(WIDTH, HEIGHT)
    start = np.asarray(task.start, np.float64)
    with BuildingRenderer(building, WIDTH, HEIGHT) as renderer:
        found = _find_door(renderer, K, start, task.yaw0)
        if found is None:
            return ["door step skipped: no door in view of the start"], {"skipped": "no door in view"}
        yaw, T, box, k, _ = found
        rgb = renderer.render(K, T, outputs=("rgb",))["rgb"]
        objects = renderer.objects
    estimator = SingleViewEstimator(vm, vv, vc, capacity=1)
    R, c, r = estimator(rgb, box[None], K, T)
    lo, hi = objects.box_min[k], objects.box_max[k]
    truth_c, truth_size = 0.5 * (lo + hi), np.sort(hi - lo)
    centre_error = float(np.linalg.norm(c[0] - truth_c))
    size_error = (2 * np.sort(r[0]) - truth_size).tolist()
    dets = mapping.Ellipsoids(
        rotation=jax.numpy.asarray(R, jax.numpy.float32),
        center=jax.numpy.asarray(c, jax.numpy.float32),
        radii=jax.numpy.asarray(r, jax.numpy.float32),
        class_id=jax.numpy.asarray([DOOR], jax.numpy.int32),
        valid=jax.numpy.asarray([True]),
    )
    store = mapping.update(mapping.init(4), dets)
    grid = mapping.semantic_grid(store, building.grid, window=None)
    goal = _goal_behind(building, lo, hi, start)
    if goal is None:
        return ["door step skipped: no free cell behind the door"], {"skipped": "no goal behind the door"}
    indoor = np.asarray(building.indoor)
    gr, gc = (int(v) for v in np.asarray(world_to_cell(goal, building.origin, building.resolution)))
    sampler = mapping.object_map_sampler(lsd_sampler, grid)
    cfg = NavConfig(n_samples=500, max_steps=150 if quick else 400)
    res = navigate(
        building, start, goal, jax.random.PRNGKey(1), cfg, sampler, yaw0=yaw, goal_outdoors=not indoor[gr, gc]
    )
    gap = np.linalg.norm(res.path - truth_c[:2], axis=-1).min() if len(res.path) else float("inf")
    through = bool(gap < 0.5 * float(np.max(hi[:2] - lo[:2])) + 0.2)
    fig_path = pathlib.Path(out_dir) / "lsd_door_demo.png"
    outline = quadrics.conic_outline(quadrics.ground_conic(R[0], c[0], r[0], xp=np), 64, xp=np)[0]
    # the estimate's outline in the image: its dual quadric projected to a dual conic (numpy: nothing compiles)
    conic = quadrics.project_dual_conic(quadrics.dual_quadric(R[0], c[0], r[0], xp=np), K, T, xp=np)
    image_outline = quadrics.conic_outline(conic, 64, xp=np)[0]
    _figure(fig_path, rgb, box, image_outline, building, lo, hi, outline, start, goal, res.path, T)
    record_output(fig_path)
    rec = {
        "door_model": meta.get("name", "volumon_door"),
        "door_object": k,
        "box": [float(v) for v in box],
        "centre_error_m": centre_error,
        "size_error_m (sorted full extents, estimate - truth)": size_error,
        "goal": [float(v) for v in goal],
        "success": bool(res.success),
        "reason": res.reason,
        "travelled_m": float(res.cost),
        "passes_the_door": through,
        "seconds": time.perf_counter() - t0,
    }
    lines = [
        f"door step: VoluMon door model on a {WIDTH}x{HEIGHT} view from the start: door {k} estimated "
        f"{centre_error:.2f} m from its true centre; LSD with that object map to a goal behind it: "
        f"{'reached' if res.success else res.reason} after {res.cost:.1f} m, path "
        f"{'passes' if through else 'does not pass'} the door ({rec['seconds']:.0f} s)",
        f"figure: {fig_path}",
    ]
    return lines, rec


def _figure(path, rgb, box, image_outline, building, lo, hi, outline, start, goal, trajectory, T):
    import matplotlib  # deferred: matplotlib is optional (the sim extra)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: matplotlib is optional (the sim extra)
    from matplotlib.patches import Rectangle

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    axes[0].imshow(rgb)
    u0, v0, u1, v1 = (float(x) for x in box)
    axes[0].add_patch(Rectangle((u0, v0), u1 - u0, v1 - v0, fill=False, ec="lime", lw=1.5, label="door box"))
    axes[0].plot(*np.vstack([image_outline, image_outline[:1]]).T, color="tab:blue", lw=1.5, label="VoluMon")
    axes[0].set_xlim(0, rgb.shape[1])
    axes[0].set_ylim(rgb.shape[0], 0)
    axes[0].legend(loc="lower right", fontsize=7)
    axes[0].set_title("robot camera: door box (segmentation) and VoluMon estimate")
    ax = axes[1]
    occ = np.asarray(building.occupancy)
    res, origin = float(building.resolution), np.asarray(building.origin, np.float64)
    H, W = occ.shape
    ax.imshow(
        occ,
        cmap="Greys",
        origin="lower",
        extent=(origin[0], origin[0] + W * res, origin[1], origin[1] + H * res),
        interpolation="nearest",
    )
    ax.add_patch(
        Rectangle((lo[0], lo[1]), hi[0] - lo[0], hi[1] - lo[1], fill=False, ec="green", lw=2, label="true door")
    )
    ax.plot(*np.vstack([outline, outline[:1]]).T, color="tab:blue", lw=2, label="VoluMon door (footprint)")
    ax.plot(*np.asarray(trajectory).T, color="tab:orange", lw=1.5, label="LSD path")
    ax.plot(*start, "o", color="k", label="start")
    ax.plot(*goal, "*", color="red", ms=12, label="goal")
    eye = -T[:3, :3].T @ T[:3, 3]
    fwd = T[2, :3]
    ax.arrow(eye[0], eye[1], 1.0 * fwd[0], 1.0 * fwd[1], width=0.05, color="k")
    pts = np.vstack([trajectory, [start], [goal], [0.5 * (lo[:2] + hi[:2])]])
    mid, span = pts.mean(0), max(np.ptp(pts, 0).max() / 2 + 2.0, 4.0)
    ax.set_xlim(mid[0] - span, mid[0] + span)
    ax.set_ylim(mid[1] - span, mid[1] + span)
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=7)
    ax.set_title("object map from one view; LSD plan through the door")
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=90)
    plt.close(fig)
