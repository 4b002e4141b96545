"""jaxsem: semantic navigation with ellipsoid objects in JAX.

The geometry core and the metrics are re-exported here; the larger parts are subpackages,
imported on first use so that ``import jaxsem`` stays light:

- :mod:`jaxsem.quadrics`  ellipsoids as dual/primal quadrics, boxes, texture planes, ground conics
- :mod:`jaxsem.metrics`   pose/shape errors, 3D IoU, ADI, AUC
- :mod:`jaxsem.factors`   ROSHAN residuals and the class shape table
- :mod:`jaxsem.slam`      batch and online solvers, initialisation, OpenCV front end, BOP sequences;
                          :mod:`jaxsem.slam.sim` simulated ellipsoid maps and camera paths
- :mod:`jaxsem.models`    flax MobileNetV2, VoluMon, LSD
- :mod:`jaxsem.data`      what every method shares: BOP and FAT readers, MuJoCo rendering, fetcher
- :mod:`jaxsem.planning`  buildings, sensors, shortest paths, PRM, navigation loop
- :mod:`jaxsem.volumon`   VoluMon losses, training, refinement, evaluation; its data in
                          :mod:`jaxsem.volumon.data`
- :mod:`jaxsem.lsd`       LSD training and the learned PRM sampler
- :mod:`jaxsem.mapping`   object maps for planning (ellipsoid estimates -> semantic grid), rendered
                          buildings and the door model
- :mod:`jaxsem.classes`   the one object class table (sizes, shapes)
"""

import importlib as _importlib
import os as _os

# MuJoCo renders headless through EGL on machines without a display; set before mujoco loads.
_os.environ.setdefault("MUJOCO_GL", "egl")

from . import quadrics as quadrics
from .quadrics import (
    algebraic_distance as algebraic_distance,
    conic_bbox as conic_bbox,
    conic_outline as conic_outline,
    dual_quadric as dual_quadric,
    ground_conic as ground_conic,
    look_at as look_at,
    primal_quadric as primal_quadric,
    project_bbox as project_bbox,
    project_dual_conic as project_dual_conic,
    rasterize_footprint as rasterize_footprint,
    surface_points as surface_points,
    texture_plane_depth as texture_plane_depth,
)

__version__ = "0.1.0"

# JAX's persistent compilation cache for library calls too (``~/.cache/jaxsem/jax``,
# ``$JAXSEM_CACHE_DIR``; ``JAXSEM_NO_COMPILATION_CACHE=1`` or a cache folder of the user's own
# leaves JAX's setting alone): see :mod:`jaxsem._cache`.
from ._cache import library_default as _library_cache

_library_cache()

_SUBPACKAGES = (
    "classes",
    "metrics",
    "factors",
    "slam",
    "sim",
    "models",
    "data",
    "planning",
    "volumon",
    "lsd",
    "mapping",
    "parallel",
    "demos",
)


def __getattr__(name):
    if name in _SUBPACKAGES:
        module = _importlib.import_module(f".{name}", __name__)
        globals()[name] = module
        return module
    raise AttributeError(f"module 'jaxsem' has no attribute {name!r}")
