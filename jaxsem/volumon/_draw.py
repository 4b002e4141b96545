"""Overlays: the projected conic (outline of the ellipsoid) and its 3D bounding box on an image."""

from __future__ import annotations

import numpy as np

from ..quadrics import conic_outline as quadrics_conic_outline, dual_quadric, project_dual_conic

_EDGES = [(0, 1), (0, 2), (1, 3), (2, 3), (4, 5), (4, 6), (5, 7), (6, 7), (0, 4), (1, 5), (2, 6), (3, 7)]


def ellipsoid_outline(rotation, center, radii, K, n: int = 100):
    """(n, 2) pixel points of the ellipse outline (camera-frame ellipsoid), or None if not an ellipse."""
    conic = project_dual_conic(dual_quadric(rotation, center, radii), K, np.eye(4))
    outline, valid = quadrics_conic_outline(conic, n)
    return np.asarray(outline, np.float64) if bool(valid) else None


def box_corners_2d(rotation, center, radii, K):
    """(8, 2) projected corners of the ellipsoid's bounding cuboid (camera frame)."""
    s = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
    P = (s * np.asarray(radii)) @ np.asarray(rotation, np.float64).T + np.asarray(center)
    uv = P @ np.asarray(K, np.float64).T
    return uv[:, :2] / np.maximum(uv[:, 2:], 1e-6)


def draw_predictions(ax, image, ellipsoids, K, boxes=None, truth=None):
    """Draw on a matplotlib axis: image, input boxes (green), conic (blue), 3D box (orange),
    optional true cuboids (dashed white). ``ellipsoids``: list of (rotation, center, radii)."""
    ax.imshow(image)
    H, W = np.asarray(image).shape[:2]
    if boxes is not None:
        for b in np.asarray(boxes):
            ax.add_patch(
                __import__("matplotlib").patches.Rectangle(b[:2], *(b[2:] - b[:2]), fill=False, color="lime", lw=1)
            )
    for R, t, r in ellipsoids:
        out = ellipsoid_outline(R, t, r, K)
        if out is not None:
            ax.plot(out[:, 0], out[:, 1], color="deepskyblue", lw=1)
        c = box_corners_2d(R, t, r, K)
        for i, j in _EDGES:
            ax.plot(c[[i, j], 0], c[[i, j], 1], color="orange", lw=0.8)
    if truth is not None:
        for R, t, h in truth:
            c = box_corners_2d(R, t, h, K)
            for i, j in _EDGES:
                ax.plot(c[[i, j], 0], c[[i, j], 1], color="white", lw=0.6, ls="--")
    ax.set_xlim(-0.5, W - 0.5)
    ax.set_ylim(H - 0.5, -0.5)
    ax.axis("off")
