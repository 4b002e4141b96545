"""The object class table: one row per class, read by every part of jaxsem.

ROSHAN's semantic shape prior (thesis section 4.3.4), the simulators, VoluMon's synthetic scenes
and its size-consistency loss (section 5.3.3) and the dataset writers all take an object's
size from here, so a "ball" is the same ball everywhere.

Conventions:

- ``dimensions`` are *full* extents in metres along the object's own x, y, z axes (the columns of
  an ellipsoid's ``rotation``); the ellipsoid's semi-axes are ``radii = dimensions / 2``.
- ``sigma`` is the standard deviation of each full extent within the class (the shape prior's
  diagonal covariance, section 4.3.4; ``radii_sigma = sigma / 2``).
- ``shape`` is how simulators draw the object: ``"cuboid"``, ``"cylinder"`` (its axis is object
  ``z``) or ``"ellipsoid"``.

Sources: a Toyota Camry (4.88 x 1.84 x 1.45 m) for "car"; an interior door leaf (0.9 m wide,
4.5 cm thick, 2.03 m tall); the YCB cracker box of the Falling Things dataset (FAT's
``cuboid_dimensions`` 16.4036 x 21.3437 x 7.18 cm) and YCB tomato soup can (6.77 cm diameter,
10.18 cm tall); the ball is slightly squashed (6.4 x 7.0 x 7.8 cm) so that its orientation is
defined.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["ObjectClass", "CLASSES", "CLASS_NAMES", "get", "index", "radii_table"]


@dataclasses.dataclass(frozen=True)
class ObjectClass:
    """One row of the class table (see the module docstring for the conventions).

    Attributes:
      name: class name, unique.
      shape: ``"cuboid"``, ``"cylinder"`` (axis along object z) or ``"ellipsoid"``.
      dimensions: full extents (x, y, z) in metres.
      sigma: standard deviation of each full extent (metres).
      color: base RGB colour in [0, 1] used by the renderers.
    """

    name: str
    shape: str
    dimensions: tuple[float, float, float]
    sigma: tuple[float, float, float]
    color: tuple[float, float, float] = (0.6, 0.6, 0.6)

    def __post_init__(self):
        if self.shape not in ("cuboid", "cylinder", "ellipsoid"):
            raise ValueError(f"shape: expected 'cuboid', 'cylinder' or 'ellipsoid', got {self.shape!r}")
        for field in ("dimensions", "sigma", "color"):
            value = getattr(self, field)
            if len(value) != 3 or not all(np.isfinite(v) for v in value):
                raise ValueError(f"{field}: expected three finite numbers, got {value!r}")
        if not all(d > 0 for d in self.dimensions):
            raise ValueError(f"dimensions: expected positive extents, got {self.dimensions!r}")
        if not all(s > 0 for s in self.sigma):
            raise ValueError(f"sigma: expected positive standard deviations, got {self.sigma!r}")

    @property
    def radii(self) -> tuple[float, float, float]:
        """Semi-axes (metres) of the class-mean ellipsoid."""
        return tuple(d / 2 for d in self.dimensions)  # type: ignore[return-value]

    @property
    def radii_sigma(self) -> tuple[float, float, float]:
        """Standard deviation of each semi-axis (metres)."""
        return tuple(s / 2 for s in self.sigma)  # type: ignore[return-value]


CLASSES: tuple[ObjectClass, ...] = (
    # Largest sigma on the length, as in the thesis, to admit longer cars.
    ObjectClass("car", "ellipsoid", (4.88, 1.84, 1.45), (0.70, 0.20, 0.15), (0.55, 0.55, 0.6)),
    # Adult standing: about 0.3 m deep, 0.5 m shoulder width, 1.7 m tall.
    ObjectClass("person", "ellipsoid", (0.30, 0.50, 1.70), (0.10, 0.10, 0.20), (0.8, 0.6, 0.5)),
    # Interior door leaf: 0.9 m wide (x), 4.5 cm thick (y), 2.03 m tall (z).
    ObjectClass("door", "cuboid", (0.90, 0.045, 2.03), (0.10, 0.01, 0.05), (0.55, 0.35, 0.2)),
    ObjectClass("chair", "cuboid", (0.50, 0.50, 0.90), (0.10, 0.10, 0.12), (0.4, 0.3, 0.2)),
    ObjectClass("cracker_box", "cuboid", (0.164036, 0.213437, 0.0718), (0.01, 0.01, 0.005), (0.85, 0.25, 0.15)),
    ObjectClass("soup_can", "cylinder", (0.0677, 0.0677, 0.1018), (0.004, 0.004, 0.006), (0.8, 0.8, 0.75)),
    ObjectClass("ball", "ellipsoid", (0.064, 0.070, 0.078), (0.005, 0.005, 0.005), (0.2, 0.45, 0.85)),
    ObjectClass("melon", "ellipsoid", (0.14, 0.14, 0.20), (0.015, 0.015, 0.02), (0.4, 0.8, 0.3)),
    # The textured meshes of robosuite 1.5.2 (jaxsem.data.robosuite_assets): full extents of the
    # compiled mesh's vertices after robosuite's mesh scale, in the mesh file's frame (z up);
    # sigma 5 % of each extent (one instance per class). The bottle's cross-section measures
    # 5.51 x 5.86 cm; the table keeps a cylinder round (their mean).
    ObjectClass("bread", "ellipsoid", (0.048, 0.040, 0.048), (0.0024, 0.002, 0.0024), (0.8, 0.6, 0.3)),
    ObjectClass("soda_can", "cylinder", (0.050, 0.050, 0.080), (0.0025, 0.0025, 0.004), (0.8, 0.1, 0.1)),
    ObjectClass("cereal_box", "cuboid", (0.100, 0.030, 0.150), (0.005, 0.0015, 0.0075), (0.9, 0.75, 0.3)),
    ObjectClass("milk_carton", "cuboid", (0.0397, 0.0397, 0.144), (0.002, 0.002, 0.0072), (0.95, 0.95, 0.95)),
    ObjectClass("lemon", "ellipsoid", (0.0675, 0.040, 0.040), (0.0034, 0.002, 0.002), (0.95, 0.85, 0.2)),
    ObjectClass("bottle", "cylinder", (0.0568, 0.0568, 0.160), (0.0028, 0.0028, 0.008), (0.6, 0.8, 0.7)),
)

CLASS_NAMES: tuple[str, ...] = tuple(c.name for c in CLASSES)
assert len(set(CLASS_NAMES)) == len(CLASS_NAMES), "class names must be unique"


def index(name: str) -> int:
    """Index of class ``name`` in :data:`CLASSES`; ``ValueError`` listing the known classes."""
    try:
        return CLASS_NAMES.index(name)
    except ValueError:
        raise ValueError(f"class name: unknown class {name!r}; known classes are {list(CLASS_NAMES)}") from None


def get(name: str) -> ObjectClass:
    """The :class:`ObjectClass` called ``name`` (``ValueError`` listing the known classes)."""
    return CLASSES[index(name)]


def radii_table(names=None, dtype=np.float64):
    """``(mean_radii (C, 3), radii_sigma (C, 3))`` numpy arrays for ``names`` (default: all classes)."""
    rows = CLASSES if names is None else tuple(get(n) for n in names)
    mean = np.array([c.radii for c in rows], dtype=dtype).reshape(len(rows), 3)
    sigma = np.array([c.radii_sigma for c in rows], dtype=dtype).reshape(len(rows), 3)
    return mean, sigma
