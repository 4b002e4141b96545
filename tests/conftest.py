"""Test environment: float64 on (precision checks), headless MuJoCo, small thread pools.

Tests that check float32 behaviour pass float32 arrays explicitly.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=true")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
