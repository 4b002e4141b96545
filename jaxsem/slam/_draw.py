"""Figures of sequences and maps: top-down ellipses, camera paths, and detections with projected
estimates over an image.
"""

from __future__ import annotations

import numpy as np

from .. import quadrics as Q
from .._checks import require_type
from ..quadrics import Camera, Ellipsoid

# --------------------------------------------------------------------------------------------
# Figures (matplotlib is imported by the caller; these only draw on the axes given).


def _ground_outline(rotation, center, radii, num_points: int = 72):
    """Top-down outline (orthographic along z) of ellipsoids: (..., num_points, 2) world x, y."""
    # numpy (xp=np): figures are host code, and eager jnp ops would each compile a program.
    R, c, r = (np.asarray(x, np.float64) for x in (rotation, center, radii))
    outline, _ = Q.conic_outline(Q.ground_conic(R, c, np.abs(r), xp=np), num_points, xp=np)
    return np.asarray(outline, np.float64)


def draw_top_down(ax, ellipsoid: Ellipsoid, mask=None, *, label=None, labels=None, **style):
    """Draws ellipsoids seen from above (world x right, y up) on matplotlib axes ``ax``.

    Args:
      ellipsoid: a :class:`jaxsem.quadrics.Ellipsoid` of J world ellipsoids (numpy or jax arrays;
        e.g. ``estimate.ellipsoid``); the absolute value of the radii is drawn.
      mask: optional (J,) bool, which ellipsoids to draw (default all).
      label: legend label (given to the first outline only).
      labels: optional (J,) strings written at the centres.
      **style: matplotlib ``plot`` keywords (colour, linestyle, linewidth...).

    Returns:
      the list of line artists.
    """
    rotation, center, radii = require_type("ellipsoid", ellipsoid, Ellipsoid)
    outline = _ground_outline(rotation, center, radii)
    outline = outline.reshape(-1, *outline.shape[-2:])  # one ellipsoid or J
    center = np.asarray(center, np.float64).reshape(-1, 3)
    mask = np.ones(len(outline), bool) if mask is None else np.asarray(mask, bool).reshape(-1)
    lines = []
    for j in np.flatnonzero(mask):
        (line,) = ax.plot(
            outline[j, :, 0],
            outline[j, :, 1],
            label=label if not lines else None,
            **style,
        )
        lines.append(line)
        if labels is not None:
            ax.text(
                center[j, 0],
                center[j, 1],
                str(labels[j]),
                fontsize=7,
                ha="center",
                va="center",
                color=style.get("color", "k"),
            )
    return lines


def draw_camera_path(
    ax,
    camera_T_world,
    *,
    arrows: int = 8,
    arrow_length: float = 2.0,
    label="camera path",
    **style,
):
    """Draws camera centres (top-down) and a few viewing directions.

    Args:
      camera_T_world: (T, 4, 4) poses (world-to-camera, OpenCV axes: the viewing direction is
        the third row of the rotation).
      arrows: number of evenly spaced heading arrows; arrow_length: metres.
    """
    pose = np.asarray(camera_T_world, np.float64).reshape(-1, 4, 4)
    R = pose[:, :3, :3]
    eye = -np.einsum("tji,tj->ti", R, pose[:, :3, 3])  # -R^T t
    forward = R[:, 2, :]
    style = {"color": "k", "lw": 1.0, **style}
    (line,) = ax.plot(eye[:, 0], eye[:, 1], label=label, **style)
    if arrows > 0 and len(eye):
        for t in np.unique(np.linspace(0, len(eye) - 1, arrows).round().astype(int)):
            d = forward[t, :2]
            n = np.linalg.norm(d)
            if n > 1e-9:
                d = d / n * arrow_length
                ax.annotate(
                    "",
                    xy=(eye[t, 0] + d[0], eye[t, 1] + d[1]),
                    xytext=(eye[t, 0], eye[t, 1]),
                    arrowprops=dict(arrowstyle="->", color=style["color"], lw=0.8),
                )
    return line


def draw_overlay(
    ax,
    image,
    camera: Camera,
    image_size,
    boxes=None,
    ids=None,
    estimate=None,
    object_ids=None,
    *,
    title=None,
    color="tab:blue",
):
    """Detections and projected estimates over one image (or a blank canvas of the image size).

    Args:
      ax: matplotlib axes.
      image: (H, W, 3) or (H, W) array, or None for a blank grey canvas of ``image_size``.
      camera: the :class:`jaxsem.quadrics.Camera` to project with (``K`` (3, 3) and the estimated
        ``camera_T_world`` (4, 4)).
      image_size: (width, height) pixels.
      boxes: optional (N, 4) measured boxes, drawn green; ids: their (N,) labels.
      estimate: optional :class:`jaxsem.quadrics.Ellipsoid` of J world ellipsoids to project
        (e.g. ``result.ellipsoid``): outline of the dual conic in blue, its box dashed.
      object_ids: optional (J,) labels of the ellipsoids; only those in ``ids`` are drawn when
        both are given (the objects detected in this frame).
      color: matplotlib colour of the projected ellipsoids (to draw two sets over one image, e.g.
        an estimate and the truth, call twice on the same axes with the same image).
    """
    K, camera_T_world = require_type("camera", camera, Camera)
    W, H = int(image_size[0]), int(image_size[1])
    if image is None:
        ax.imshow(np.full((H, W, 3), 0.92), extent=(0, W, H, 0))
    else:
        ax.imshow(
            np.asarray(image),
            extent=(0, W, H, 0),
            cmap="gray" if np.ndim(image) == 2 else None,
        )
    ax.set_xlim(0, W)
    ax.set_ylim(H, 0)
    if boxes is not None:
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        for i, b in enumerate(boxes):
            ax.add_patch(_rect(b, color="tab:green", lw=1.5))
            if ids is not None:
                ax.text(b[0], b[1] - 3, str(ids[i]), color="tab:green", fontsize=7)
    if estimate is not None:
        rotation, center, radii = (np.asarray(x, np.float64) for x in require_type("estimate", estimate, Ellipsoid))
        keep = np.ones(len(center), bool)
        if ids is not None and object_ids is not None:
            wanted = {str(i) for i in ids}
            keep = np.array([str(o) in wanted for o in object_ids], bool)
        if keep.any():
            # numpy (xp=np): host code, nothing compiles. The conic is a real ellipse and its
            # centre in front of the camera exactly where project_bbox calls the box valid.
            Kn = np.asarray(K, np.float64)
            pose = np.asarray(camera_T_world, np.float64)
            R, c, r = (x[keep] for x in (rotation, center, radii))
            conic = Q.project_dual_conic(Q.dual_quadric(R, c, r, xp=np), Kn, pose, xp=np)
            outline, ok_c = Q.conic_outline(conic, 96, xp=np)
            pbox, ok_b = Q.conic_bbox(conic, xp=np)
            ok_b = ok_b & (Q.camera_depth(c, pose, xp=np) > 0)
            for k in range(int(keep.sum())):
                if bool(ok_b[k]) and bool(ok_c[k]):
                    pts = np.asarray(outline[k])
                    ax.plot(pts[:, 0], pts[:, 1], color=color, lw=1.2)
                    ax.add_patch(_rect(np.asarray(pbox[k]), color=color, lw=0.8, ls="--"))
    if title:
        ax.set_title(title, fontsize=9)
    ax.set_xticks([])
    ax.set_yticks([])


def _rect(b, **style):
    import matplotlib.patches as mpatches  # deferred: matplotlib is optional (the sim extra)

    return mpatches.Rectangle((b[0], b[1]), b[2] - b[0], b[3] - b[1], fill=False, **style)
