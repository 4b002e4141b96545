"""JAX's persistent compilation cache for jaxsem: compile time is part of the user's wait, and a
second process that solves the same shapes loads the programs instead of compiling them again.

On by default for every command and every library call (``import jaxsem`` turns it on unless the
user has set ``jax_compilation_cache_dir`` already, or ``JAXSEM_NO_COMPILATION_CACHE=1``);
:func:`enable_compilation_cache` chooses the folder or turns it off.
"""

from __future__ import annotations

import os
import pathlib
import sys

import jax

NO_CACHE_ENV = "JAXSEM_NO_COMPILATION_CACHE"


def enable_compilation_cache(cache_dir: str | None = None, enabled: bool | None = None) -> str | None:
    """Turns on JAX's persistent compilation cache (compile time is part of the user's wait);
    returns its folder, or None when it is off.

    The folder is ``cache_dir``, else ``$JAXSEM_CACHE_DIR``, else ``~/.cache/jaxsem/jax``.
    ``enabled=False`` (``--no-compilation-cache``) turns it off instead, as does
    ``JAXSEM_NO_COMPILATION_CACHE=1`` when ``enabled`` is None.
    """
    if enabled is None:
        enabled = os.environ.get(NO_CACHE_ENV, "") not in ("1", "true", "yes")
    if not enabled:
        jax.config.update("jax_compilation_cache_dir", None)
        return None
    cache_dir = cache_dir or os.environ.get("JAXSEM_CACHE_DIR", str(pathlib.Path.home() / ".cache" / "jaxsem" / "jax"))
    try:
        jax.config.update("jax_compilation_cache_dir", cache_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.1)
    except Exception as exc:  # an old jax without the option: run uncached
        print(f"jaxsem: compilation cache disabled ({exc})", file=sys.stderr)
        return None
    return cache_dir


def library_default() -> str | None:
    """The cache for library calls, at ``import jaxsem``: on (:func:`enable_compilation_cache`)
    unless ``JAXSEM_NO_COMPILATION_CACHE=1`` or the user has set JAX's cache folder themselves
    (their choice is kept). Returns the folder in use, or None."""
    if os.environ.get(NO_CACHE_ENV, "") in ("1", "true", "yes"):
        return None
    mine = getattr(jax.config, "jax_compilation_cache_dir", None)
    if mine:
        return mine
    return enable_compilation_cache()
