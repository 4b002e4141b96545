"""Overlays: the projected conic (outline of the ellipsoid) and its 3D bounding box on an image."""

from __future__ import annotations

import numpy as np

from .._checks import require_type
from ..quadrics import (
    Ellipsoid,
    conic_outline as quadrics_conic_outline,
    cuboid_corners,
    dual_quadric,
    project_dual_conic,
    project_points,
)

# edges of a cuboid in jaxsem.quadrics.CUBOID_CORNER_SIGNS order: front face, rear face, front to rear
_EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]


def ellipsoid_outline(ellipsoid: Ellipsoid, K, n: int = 100):
    """(n, 2) pixel points of the ellipse outline of a camera-frame :class:`~jaxsem.quadrics.Ellipsoid`
    (VoluMon's output), or None if not an ellipse.

    Computed in float64 (a figure's outline): a float32 prediction or ``K`` would otherwise meet
    the float64 identity pose, which strict dtype promotion refuses."""
    require_type("ellipsoid", ellipsoid, Ellipsoid)
    rotation, center, radii, K = (np.asarray(x, np.float64) for x in (*ellipsoid, K))
    conic = project_dual_conic(dual_quadric(rotation, center, radii), K, np.eye(4))
    outline, valid = quadrics_conic_outline(conic, n)
    return np.asarray(outline, np.float64) if bool(valid) else None


def box_corners_2d(ellipsoid: Ellipsoid, K):
    """(8, 2) projected corners of a camera-frame :class:`~jaxsem.quadrics.Ellipsoid`'s bounding
    cuboid (a cuboid's half extents in ``radii`` give the cuboid), in
    :data:`jaxsem.quadrics.CUBOID_CORNER_SIGNS` order; meaningless for corners behind the camera."""
    corners = cuboid_corners(*require_type("ellipsoid", ellipsoid, Ellipsoid), xp=np)
    return project_points(corners, K, np.eye(4), xp=np)[0]


def draw_predictions(ax, image, ellipsoids, K, boxes=None, truth=None):
    """Draw on a matplotlib axis: image, input boxes (green), conic (blue), 3D box (orange),
    optional true cuboids (dashed white). ``ellipsoids``: camera-frame :class:`~jaxsem.quadrics.Ellipsoid`
    s (or ``(rotation, center, radii)`` triples); ``truth``: the same with half extents as radii."""
    ax.imshow(image)
    H, W = np.asarray(image).shape[:2]
    if boxes is not None:
        for b in np.asarray(boxes):
            ax.add_patch(
                __import__("matplotlib").patches.Rectangle(b[:2], *(b[2:] - b[:2]), fill=False, color="lime", lw=1)
            )
    for e in ellipsoids:
        e = Ellipsoid(*e)
        out = ellipsoid_outline(e, K)
        if out is not None:
            ax.plot(out[:, 0], out[:, 1], color="deepskyblue", lw=1)
        c = box_corners_2d(e, K)
        for i, j in _EDGES:
            ax.plot(c[[i, j], 0], c[[i, j], 1], color="orange", lw=0.8)
    if truth is not None:
        for cuboid in truth:
            c = box_corners_2d(Ellipsoid(*cuboid), K)
            for i, j in _EDGES:
                ax.plot(c[[i, j], 0], c[[i, j], 1], color="white", lw=0.6, ls="--")
    ax.set_xlim(-0.5, W - 0.5)
    ax.set_ylim(H - 0.5, -0.5)
    ax.axis("off")
