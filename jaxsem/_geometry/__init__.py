"""The geometry core's implementation, one module per job (private: import :mod:`jaxsem.quadrics`).

:mod:`jaxsem.quadrics` re-exports every public name and documents the conventions; its module
docstring lists which module holds what. These modules import nothing of jaxsem but
``jaxsem._checks`` and each other.
"""
