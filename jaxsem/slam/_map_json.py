"""Estimated maps as JSON (:func:`map_to_json`) and their errors against a sequence's truth
(:func:`truth_errors`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import jax
import numpy as np

from .._checks import require_type
from ..metrics import ellipsoid_errors
from ..quadrics import Ellipsoid

if TYPE_CHECKING:
    from ._run_sequence import SequenceResult


def map_to_json(object_ids, object_classes, ellipsoid: Ellipsoid, camera_T_world=None) -> dict:
    """An estimated map as a JSON-ready dict.

    Args:
      object_ids: (J,) association ids; object_classes: (J,) class names.
      ellipsoid: the J world ellipsoids, a :class:`jaxsem.quadrics.Ellipsoid`.
      camera_T_world: optional (T, 4, 4) estimated poses, written as ``"camera_T_world"``.

    Returns:
      ``{"format", "frame": "world", "units": "metres", "objects": [{"id", "class", "center",
      "radii", "rotation"}], ["camera_T_world"]}``. ``SequenceResult`` fields fit directly:
      ``map_to_json(r.object_ids, r.object_classes, r.ellipsoid, r.camera_T_world)``.
    """
    rotation, center, radii = require_type("ellipsoid", ellipsoid, Ellipsoid)
    rotation = np.asarray(rotation, np.float64).reshape(-1, 3, 3)
    center = np.asarray(center, np.float64).reshape(-1, 3)
    radii = np.asarray(radii, np.float64).reshape(-1, 3)
    J = len(object_ids)
    if not (len(object_classes) == rotation.shape[0] == center.shape[0] == radii.shape[0] == J):
        raise ValueError(
            f"object_ids, object_classes, ellipsoid (rotation, center, radii): expected {J} objects each, got "
            f"{len(object_classes)}, {rotation.shape[0]}, {center.shape[0]}, {radii.shape[0]}"
        )
    out = {
        "format": "jaxsem.roshan.map/1",
        "frame": "world",
        "units": "metres",
        "objects": [
            {
                "id": object_ids[j],
                "class": object_classes[j],
                "center": center[j].tolist(),
                "radii": radii[j].tolist(),
                "rotation": rotation[j].tolist(),
            }
            for j in range(J)
        ],
    }
    if camera_T_world is not None:
        out["camera_T_world"] = np.asarray(camera_T_world, np.float64).tolist()
    return out


def truth_errors(result: SequenceResult, truth: Mapping) -> dict:
    """Per-object errors of ``result`` against ``sequence.truth`` (matched by id).

    Returns:
      ``{"ids": [...], "shape": (K,), "position": (K,), "orientation": (K,) deg, "mean": {metric:
      float}}`` over the K estimated objects that have a true counterpart
      (:func:`jaxsem.metrics.ellipsoid_errors`, symmetry-aware).
    """
    by_id = {o["id"]: o for o in truth.get("objects", [])}
    keep = [j for j, i in enumerate(result.object_ids) if i in by_id]
    out: dict = {"ids": [result.object_ids[j] for j in keep]}
    if not keep:
        return {
            **out,
            "shape": np.zeros(0),
            "position": np.zeros(0),
            "orientation": np.zeros(0),
            "mean": {},
        }
    tr = [by_id[result.object_ids[j]] for j in keep]
    # One jitted program (op by op, each jnp op would compile a program of its own).
    e = jax.jit(ellipsoid_errors)(
        result.rotation[keep],
        result.center[keep],
        result.radii[keep],
        np.stack([o["rotation"] for o in tr]),
        np.stack([o["center"] for o in tr]),
        np.stack([o["radii"] for o in tr]),
    )
    for k, v in e.items():
        out[k] = np.asarray(v, np.float64)
    out["mean"] = {k: float(np.mean(out[k])) for k in ("shape", "position", "orientation")}
    return out
