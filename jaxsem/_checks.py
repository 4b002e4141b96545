"""Argument checks at the Python boundary, shared by the package.

They live in :mod:`jaxsem.quadrics` (which imports nothing else of the package) and are
re-exported here for the other modules.
"""

from .quadrics import _as_float_array as as_float_array
from .quadrics import _batch_shape as batch_shape
from .quadrics import _is_concrete as is_concrete

__all__ = ["as_float_array", "batch_shape", "is_concrete"]
