"""The object class table: one row per class, read by every part of jaxsem.

ROSHAN's semantic shape prior (thesis section 4.3.4), the simulators, VoluMon's synthetic scenes
and its size-consistency loss (section 5.3.3) and the dataset writers all take an object's
size from here, so a "ball" is the same ball everywhere.

A user adds classes without touching this module: :class:`ClassTable` is an immutable table
(the built-in one is :data:`DEFAULT_TABLE`, the 14 rows of :data:`CLASSES` in their order, so
their indices never change); ``DEFAULT_TABLE.with_class("mug", (0.12, 0.09, 0.1), (0.01, 0.01,
0.01), "cylinder")`` returns a new table with a 15th row, :meth:`ClassTable.from_json` reads
rows from a file (see :meth:`ClassTable.to_json` for the layout). There is no process-global
registry: a table is a value, and a ROSHAN problem keeps the table it was built with
(``jaxsem.slam.make_problem(..., classes=table)``), so a later table cannot change it.

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
import json
import os

import numpy as np

__all__ = [
    "CLASSES",
    "CLASS_NAMES",
    "DEFAULT_TABLE",
    "ClassTable",
    "ObjectClass",
    "get",
    "index",
    "radii_table",
    "as_table",
]


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
    # The textured meshes of robosuite 1.5.2 (jaxsem.volumon.data.robosuite_assets): full extents of the
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


_SHAPES = ("cuboid", "cylinder", "ellipsoid")


def _triple(where: str, value) -> tuple[float, float, float]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: expected three numbers, got {value!r}") from None
    if len(out) != 3:
        raise ValueError(f"{where}: expected three numbers, got {value!r}")
    return out  # type: ignore[return-value]


@dataclasses.dataclass(frozen=True)
class ClassTable:
    """An immutable class table: rows of :class:`ObjectClass`, indexed by position.

    A value, not a registry: :meth:`with_class` and :meth:`from_json` return new tables and
    nothing global changes. Hashable (a jitted function may hold one as a static argument or
    closure; the ROSHAN problems keep theirs as a static field), and its arrays
    (:meth:`radii_table`) are what the solvers use. The first rows of a table extended from
    :data:`DEFAULT_TABLE` are the built-in classes, with their indices and priors unchanged.

    Attributes:
      rows: tuple of :class:`ObjectClass` with unique names.
    """

    rows: tuple[ObjectClass, ...]

    def __post_init__(self):
        rows = tuple(self.rows)
        if not rows:
            raise ValueError("rows: a class table needs at least one class")
        for r in rows:
            if not isinstance(r, ObjectClass):
                raise ValueError(f"rows: expected ObjectClass rows, got {type(r).__name__}")
        names = [r.name for r in rows]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"rows: class names must be unique, {dup} appear more than once")
        object.__setattr__(self, "rows", rows)

    # ---- lookup -------------------------------------------------------------------------

    @property
    def names(self) -> tuple[str, ...]:
        """Class names in index order."""
        return tuple(r.name for r in self.rows)

    def __len__(self) -> int:
        return len(self.rows)

    def __contains__(self, name) -> bool:
        return name in self.names

    def index(self, name: str) -> int:
        """Index of class ``name``; ``ValueError`` listing the known classes."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"class name: unknown class {name!r}; known classes are {list(self.names)}") from None

    def get(self, name: str) -> ObjectClass:
        """The row called ``name`` (``ValueError`` listing the known classes)."""
        return self.rows[self.index(name)]

    def indices(self, classes, where: str = "class") -> np.ndarray:
        """(N,) int64 indices of ``classes``: names (resolved with :meth:`index`) or indices
        (checked to lie in ``[0, len(self))``). ``ValueError`` names ``where`` and the bad entry."""
        arr = np.asarray(classes)
        if arr.dtype.kind in "USO":
            names = self.names
            unknown = [str(c) for c in arr.reshape(-1) if str(c) not in names]
            if unknown:
                raise ValueError(f"{where}: unknown class {unknown[0]!r}; known classes are {list(names)}")
            return np.array([names.index(str(c)) for c in arr.reshape(-1)], np.int64)
        if arr.size and arr.dtype.kind not in "iu":
            if arr.dtype.kind != "f" or not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
                raise ValueError(
                    f"{where}: expected class names or integer indices, got {arr.reshape(-1)[:5].tolist()}"
                )
        out = arr.astype(np.int64).reshape(-1)
        bad = (out < 0) | (out >= len(self))
        if np.any(bad):
            raise ValueError(
                f"{where}: indices must be in [0, {len(self)}) (classes {list(self.names)}), got {out[bad][:5].tolist()}"
            )
        return out

    def radii_table(self, dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
        """``(mean_radii (C, 3), radii_sigma (C, 3))`` numpy arrays in index order: the semantic
        shape prior of every ROSHAN solver (semi-axes, half the full dimensions)."""
        mean = np.array([r.radii for r in self.rows], dtype=dtype).reshape(len(self), 3)
        sigma = np.array([r.radii_sigma for r in self.rows], dtype=dtype).reshape(len(self), 3)
        return mean, sigma

    # ---- new tables ---------------------------------------------------------------------

    def with_class(
        self,
        name: str,
        dimensions,
        sigma,
        shape: str = "ellipsoid",
        color=(0.6, 0.6, 0.6),
        *,
        replace: bool = False,
    ) -> ClassTable:
        """A new table with class ``name`` added as the last row (full ``dimensions`` (x, y, z)
        and their standard deviations ``sigma`` in metres, ``shape`` as :class:`ObjectClass`).

        A name already in the table raises ``ValueError`` unless ``replace=True``, which changes
        that row in place (its index kept)."""
        if not isinstance(name, str) or not name:
            raise ValueError(f"name: expected a non-empty string, got {name!r}")
        row = ObjectClass(
            name, shape, _triple("dimensions", dimensions), _triple("sigma", sigma), _triple("color", color)
        )
        if name in self:
            if not replace:
                raise ValueError(f"name: class {name!r} is already in the table (pass replace=True to change it)")
            rows = tuple(row if r.name == name else r for r in self.rows)
        else:
            rows = self.rows + (row,)
        return ClassTable(rows)

    def with_classes(self, other: ClassTable, *, replace: bool = False) -> ClassTable:
        """This table with the rows of ``other`` added (or changed, with ``replace``) in order."""
        table = self
        for r in other.rows:
            table = table.with_class(r.name, r.dimensions, r.sigma, r.shape, r.color, replace=replace)
        return table

    # ---- JSON -----------------------------------------------------------------------------

    def to_dict(self) -> dict:
        """``{"classes": [{"name", "shape", "dimensions", "sigma", "color"}, ...]}``."""
        return {
            "classes": [
                dataclasses.asdict(r) | {k: list(getattr(r, k)) for k in ("dimensions", "sigma", "color")}
                for r in self.rows
            ]
        }

    @classmethod
    def from_dict(cls, data, *, base: ClassTable | None = None, where: str = "classes") -> ClassTable:
        """Inverse of :meth:`to_dict`. With ``base``, the rows are added to it (as
        :meth:`with_class`; a name already in ``base`` raises). Each row needs ``name``,
        ``dimensions`` and ``sigma``; ``shape`` defaults to ``"ellipsoid"``, ``color`` to grey.
        Errors name ``where``, the row and the field."""
        rows = data.get("classes") if isinstance(data, dict) else data
        if not isinstance(rows, list):
            raise ValueError(f"{where}: expected {{'classes': [rows]}} or a list of rows, got {type(data).__name__}")
        table = base
        for i, row in enumerate(rows):
            at = f"{where}[{i}]"
            if not isinstance(row, dict):
                raise ValueError(f"{at}: expected an object with name, dimensions, sigma, got {row!r}")
            unknown = set(row) - {"name", "shape", "dimensions", "sigma", "color"}
            if unknown:
                raise ValueError(f"{at}: unknown fields {sorted(unknown)}")
            for key in ("name", "dimensions", "sigma"):
                if key not in row:
                    raise ValueError(f"{at}.{key}: missing")
            try:
                obj = ObjectClass(
                    str(row["name"]),
                    str(row.get("shape", "ellipsoid")),
                    _triple(f"{at}.dimensions", row["dimensions"]),
                    _triple(f"{at}.sigma", row["sigma"]),
                    _triple(f"{at}.color", row.get("color", (0.6, 0.6, 0.6))),
                )
            except ValueError as exc:
                raise ValueError(f"{at}: {exc}") from None
            if table is None:
                table = ClassTable((obj,))
            else:
                try:
                    table = table.with_class(obj.name, obj.dimensions, obj.sigma, obj.shape, obj.color)
                except ValueError as exc:
                    raise ValueError(f"{at}: {exc}") from None
        if table is None:
            raise ValueError(f"{where}: no classes")
        return table

    def to_json(self, path: str | os.PathLike) -> None:
        """Writes :meth:`to_dict` as JSON (read it back with :meth:`from_json`)."""
        with open(path, "w") as f:
            json.dump(self.to_dict(), f, indent=1)
            f.write("\n")

    @classmethod
    def from_json(cls, path: str | os.PathLike, *, base: ClassTable | None = None) -> ClassTable:
        """A table from a JSON file of :meth:`to_dict`'s layout; with ``base`` (e.g.
        :data:`DEFAULT_TABLE`) the file's rows are added after the base's. Errors name the
        file, the row and the field; a file that cannot be read, is over 16 MiB
        (checked before a byte is read), is not UTF-8 or not JSON is refused naming it."""
        try:
            size = os.stat(path).st_size
            if size > _MAX_TABLE_BYTES:
                raise ValueError(f"{path}: {size:,} bytes, more than a class table's {_MAX_TABLE_BYTES:,}")
            with open(path, "rb") as f:
                text = f.read().decode("utf-8")
            data = json.loads(text)
        except OSError as exc:
            raise ValueError(f"{path}: cannot read the class table ({exc.strerror or exc})") from None
        except UnicodeDecodeError as exc:
            raise ValueError(f"{path}: not a readable class table (not UTF-8 text: byte {exc.start})") from None
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON (line {exc.lineno}: {exc.msg})") from None
        return cls.from_dict(data, base=base, where=f"{path}: classes")


#: The largest class-table file :meth:`ClassTable.from_json` reads: 16 MiB, thousands of times a
#: table of hundreds of classes (a few hundred bytes each).
_MAX_TABLE_BYTES = 2**24


#: The built-in table: the rows of :data:`CLASSES`, in their order.
DEFAULT_TABLE = ClassTable(CLASSES)


def as_table(classes: ClassTable | None) -> ClassTable:
    """``classes`` or :data:`DEFAULT_TABLE` when None (``ValueError`` for anything else)."""
    if classes is None:
        return DEFAULT_TABLE
    if not isinstance(classes, ClassTable):
        raise ValueError(f"classes: expected a jaxsem.classes.ClassTable or None, got {type(classes).__name__}")
    return classes
