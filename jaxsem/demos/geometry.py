"""Geometry demo: random ellipsoids seen by a camera; boxes drawn tightly around projected conics."""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from .. import quadrics as q
from ..scripting import atomic_savefig

CLASS_COLOURS = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown"]


def make_scene(seed: int = 0, num_objects: int = 6):
    """A camera 1.5 m above the ground looking along +y at ellipsoids resting on the ground."""
    key = jax.random.PRNGKey(seed)
    k_pos, k_rad, k_yaw = jax.random.split(key, 3)
    radii = jax.random.uniform(k_rad, (num_objects, 3), minval=0.3, maxval=1.5)
    xy = jax.random.uniform(k_pos, (num_objects, 2), minval=jnp.array([-6.0, 6.0]), maxval=jnp.array([6.0, 18.0]))
    center = jnp.concatenate([xy, radii[:, 2:3]], axis=1)  # resting on z = 0
    yaw = jax.random.uniform(k_yaw, (num_objects,), minval=-jnp.pi, maxval=jnp.pi)
    rotation = q.so3_exp(jnp.stack([0 * yaw, 0 * yaw, yaw], axis=-1))  # yaw about world z
    K = jnp.array([[525.0, 0.0, 320.0], [0.0, 525.0, 240.0], [0.0, 0.0, 1.0]])
    camera_T_world = q.look_at(jnp.array([0.0, -2.0, 1.5]), jnp.array([0.0, 10.0, 1.0]))
    return rotation, center, radii, K, camera_T_world


def run(out_dir: pathlib.Path, quick: bool = False) -> str:
    import matplotlib  # deferred: matplotlib is optional (the sim extra)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: matplotlib is optional (the sim extra)
    from matplotlib.patches import Rectangle

    out_dir = pathlib.Path(out_dir)
    rotation, center, radii, K, pose = make_scene(num_objects=4 if quick else 6)
    box, valid = jax.jit(q.project_bbox)(rotation, center, radii, K, pose)
    depth, depth_valid = q.texture_plane_depth(rotation, center, radii, pose)
    conics = q.project_dual_conic(q.dual_quadric(rotation, center, radii), K, pose)
    outline, _ = q.conic_outline(conics, 200)
    # An independent check drawn beside: dense surface points projected into the image.
    pts = q.surface_points(jax.random.PRNGKey(1), rotation, center, radii, 4000)
    pix, _ = q.project_points(pts, K, pose)
    footprint = q.rasterize_footprint(
        rotation, center, radii, jnp.arange(1, len(radii) + 1), (250, 200), jnp.array([-10.0, -3.0]), 0.1
    )

    fig, (ax_img, ax_top) = plt.subplots(1, 2, figsize=(13, 5))
    ax_img.set_xlim(0, 640)
    ax_img.set_ylim(480, 0)
    ax_img.set_aspect("equal")
    ax_img.set_xlabel("u (px)")
    ax_img.set_ylabel("v (px)")
    ax_img.set_title("image: projected conics (lines), boxes (dashed), surface samples (dots)")
    for i in range(len(radii)):
        colour = CLASS_COLOURS[i % len(CLASS_COLOURS)]
        ax_img.scatter(pix[i, :, 0], pix[i, :, 1], s=0.2, color=colour, alpha=0.25)
        ax_img.plot(outline[i, :, 0], outline[i, :, 1], color=colour, lw=1.5)
        u0, v0, u1, v1 = np.asarray(box[i])
        ax_img.add_patch(Rectangle((u0, v0), u1 - u0, v1 - v0, fill=False, ls="--", color=colour))
        ax_img.text(u0, v0 - 4, f"#{i}", color=colour, fontsize=8)
    ax_img.add_patch(Rectangle((0, 0), 640, 480, fill=False, color="k"))
    from matplotlib.colors import ListedColormap  # deferred: matplotlib is optional (the sim extra)

    n = len(radii)
    cmap = ListedColormap(["white"] + [CLASS_COLOURS[i % len(CLASS_COLOURS)] for i in range(n)])
    ax_top.imshow(np.asarray(footprint), origin="lower", extent=(-10, 10, -3, 22), cmap=cmap, vmin=-0.5, vmax=n + 0.5)
    ax_top.plot([0], [-2], "k^", ms=8)
    ax_top.set_title("top-down footprints (rasterize_footprint), camera at the triangle")
    ax_top.set_xlabel("x (m)")
    ax_top.set_ylabel("y (m)")
    fig.tight_layout()
    path = out_dir / "geometry_boxes.png"
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)

    rows = [
        "| # | centre depth (m) | texture depth (m) | box [u_min, v_min, u_max, v_max] (px) | valid |",
        "|---|---|---|---|---|",
    ]
    cam_depth = q.camera_depth(center, pose)
    for i in range(len(radii)):
        b = ", ".join(f"{x:7.1f}" for x in np.asarray(box[i]))
        rows.append(f"| {i} | {float(cam_depth[i]):.2f} | {float(depth[i]):.2f} | [{b}] | {bool(valid[i])} |")
    rows.append(f"\nwrote {path}")
    return "\n".join(rows)
