"""Data parallelism past one device and one machine: a Mesh with a ``data`` axis, sharded vmaps.

Most jaxsem work is a ``vmap`` over independent items (maps to solve, navigation trials, images of
a batch). This module spreads such a batch over every device in a one-axis :class:`jax.sharding.Mesh`
(axis ``"data"``), on one host or many:

- :func:`data_mesh` (all of ``jax.devices()``, every host's), :func:`batch_sharding`,
  :func:`replicated`;
- :func:`pad_batch` / :func:`unpad_batch`: pad the leading axis to a multiple of the device count
  by repeating the last item (a copy of real data, so padded work is finite and as costly as real
  work, never degenerate zeros), and cut it off again;
- :func:`shard_batch`: put a batch pytree on the mesh, split along its leading axis (on several
  hosts each process passes its own slice: :func:`jax.make_array_from_process_local_data`);
- :func:`sharded_vmap`: ``sharded_vmap(fn)(*args)`` equals ``jax.vmap(fn)(*args)`` but runs each
  device's slice of the batch on that device. ``method="shard_map"`` (default) compiles
  ``vmap(fn)`` once per device slice, so a ``while_loop`` inside ``fn`` (a Levenberg-Marquardt
  solve) stops on each device when that device's slowest item stops; ``method="jit"`` lets XLA's
  partitioner split ``jit(vmap(fn))`` by the input / output shardings (one global loop);
- (batch SLAM evaluation over the devices is :func:`jaxsem.slam.solve_maps`, built on
  :func:`sharded_vmap`: this module imports no method);
- :func:`initialize_distributed`: ``jax.distributed.initialize`` when there is more than one
  process, a no-op otherwise, so the same script runs on a laptop and on a cluster.

Training runs data-parallel with the same mesh: ``jaxsem.volumon.train_and_evaluate(...,
mesh=data_mesh())`` and ``jaxsem.lsd.train_and_evaluate(..., mesh=data_mesh())`` (commands:
``--devices N|all``) keep parameters and optimiser state :func:`replicated` and split each batch
along its leading axis (:func:`batch_sharding`), so one step equals the single-device step up to
floating-point summation order.

Multi-host launch (one process per host; every process runs the same script)::

    # on each of N hosts, with host 0 reachable at 10.0.0.1:
    JAX_COORDINATOR_ADDRESS=10.0.0.1:1234 JAX_NUM_PROCESSES=N JAX_PROCESS_ID=<i> \\
        python benchmarks/scaling.py
    # under SLURM (srun -N 2 --ntasks-per-node=1 ...) or Open MPI (mpirun -np 2 ...) the
    # coordinator, process count and id are detected from the environment.

and in the script, before any other JAX call::

    from jaxsem import parallel
    parallel.initialize_distributed()
    mesh = parallel.data_mesh()          # every device of every host
    solve_all = parallel.sharded_vmap(solve_one, mesh)

On one CPU host, ``XLA_FLAGS=--xla_force_host_platform_device_count=4`` (set before JAX starts)
gives four CPU devices, which is how ``tests/slam/test_parallel.py`` checks that sharded results equal
single-device ones.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import overload

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

__all__ = [
    "DATA_AXIS",
    "batch_sharding",
    "check_batch_size",
    "data_mesh",
    "devices_mesh",
    "initialize_distributed",
    "pad_batch",
    "parse_devices",
    "replicated",
    "shard_batch",
    "sharded_vmap",
    "unpad_batch",
]

DATA_AXIS = "data"


def initialize_distributed(
    coordinator_address: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
    *,
    local_device_ids: int | Sequence[int] | None = None,
    force: bool = False,
    **kwargs,
) -> bool:
    """Joins a multi-process JAX run when there is one; returns True if JAX is distributed.

    Calls :func:`jax.distributed.initialize` (which must come before any other JAX call) when an
    argument is given, ``JAX_COORDINATOR_ADDRESS`` is set, SLURM or Open MPI report more than one
    task, or ``force`` is True (e.g. Cloud TPU pods, where JAX detects everything itself).
    Otherwise it does nothing and returns False, so single-machine runs need no flags. Calling it
    again after a successful start returns True. ``kwargs`` go to ``jax.distributed.initialize``.
    """
    if jax.distributed.is_initialized():
        return True
    env = os.environ
    multi_task = any(int(env.get(name, "1") or "1") > 1 for name in ("SLURM_NTASKS", "OMPI_COMM_WORLD_SIZE"))
    explicit = any(v is not None for v in (coordinator_address, num_processes, process_id))
    if not (explicit or force or multi_task or env.get("JAX_COORDINATOR_ADDRESS")):
        return False
    if num_processes is None and env.get("JAX_NUM_PROCESSES"):
        num_processes = int(env["JAX_NUM_PROCESSES"])
    if process_id is None and env.get("JAX_PROCESS_ID"):
        process_id = int(env["JAX_PROCESS_ID"])
    jax.distributed.initialize(
        coordinator_address=coordinator_address,
        num_processes=num_processes,
        process_id=process_id,
        local_device_ids=local_device_ids,
        **kwargs,
    )
    return True


def data_mesh(devices: Sequence | None = None, axis_name: str = DATA_AXIS) -> Mesh:
    """A one-axis :class:`~jax.sharding.Mesh` over ``devices`` (default: ``jax.devices()``, which
    after :func:`initialize_distributed` are the devices of every process)."""
    devs = list(jax.devices() if devices is None else devices)
    if not devs:
        raise ValueError("devices: expected at least one device, got an empty sequence")
    return Mesh(np.array(devs, dtype=object), (axis_name,))


def _mesh(mesh: Mesh | None) -> Mesh:
    if mesh is None:
        return data_mesh()
    if not isinstance(mesh, Mesh) or len(mesh.axis_names) != 1:
        raise ValueError(f"mesh: expected a one-axis jax.sharding.Mesh (data_mesh()), got {mesh!r}")
    return mesh


def batch_sharding(mesh: Mesh | None = None) -> NamedSharding:
    """Leading axis split over the mesh's (only) axis, the rest replicated."""
    mesh = _mesh(mesh)
    return NamedSharding(mesh, PartitionSpec(mesh.axis_names[0]))


def replicated(mesh: Mesh | None = None) -> NamedSharding:
    """Every device holds the whole array."""
    return NamedSharding(_mesh(mesh), PartitionSpec())


def _batch_size(tree, name: str) -> int:
    leaves = jax.tree_util.tree_leaves(tree)
    if not leaves:
        raise ValueError(f"{name}: expected a pytree with array leaves, got {tree!r}")
    sizes = {int(np.shape(x)[0]) if np.ndim(x) else -1 for x in leaves}
    if len(sizes) != 1 or -1 in sizes:
        shapes = [tuple(np.shape(x)) for x in leaves]
        raise ValueError(f"{name}: every leaf needs the same leading (batch) axis, got leaf shapes {shapes}")
    return sizes.pop()


def pad_batch(tree, multiple: int):
    """Pads every leaf's leading axis to a multiple of ``multiple`` by repeating the last item.

    Returns ``(padded, n)`` with ``n`` the original batch size (for :func:`unpad_batch`).
    """
    if not isinstance(multiple, (int, np.integer)) or multiple < 1:
        raise ValueError(f"multiple: expected a positive int, got {multiple!r}")
    n = _batch_size(tree, "tree")
    if n == 0:
        raise ValueError("tree: the batch is empty (leading axis 0)")
    pad = (-n) % int(multiple)
    if pad == 0:
        return tree, n

    def one(x):
        x = jnp.asarray(x)
        tail = jnp.broadcast_to(x[-1:], (pad, *x.shape[1:]))
        return jnp.concatenate([x, tail], axis=0)

    return jax.tree_util.tree_map(one, tree), n


def unpad_batch(tree, n: int):
    """The first ``n`` items of every leaf (undoes :func:`pad_batch`)."""
    return jax.tree_util.tree_map(lambda x: x[:n], tree)


def shard_batch(tree, mesh: Mesh | None = None, *, process_local: bool = False):
    """Places a batch pytree on ``mesh``, split along the leading axis.

    The leading axis must be a multiple of the device count (:func:`pad_batch`). With
    ``process_local=True`` each process passes only its own slice of the global batch (multi-host
    input pipelines); the global batch is the processes' slices in process order.
    """
    sharding = batch_sharding(mesh)
    n_dev = sharding.mesh.size
    n = _batch_size(tree, "tree")
    if process_local:
        n_local = len(sharding.mesh.local_devices or ())
        if n % n_local:
            raise ValueError(
                f"tree: the local batch ({n}) must be a multiple of the local device count ({n_local}); use pad_batch"
            )
        return jax.tree_util.tree_map(
            lambda x: jax.make_array_from_process_local_data(sharding, np.asarray(x)),
            tree,
        )
    if n % n_dev:
        raise ValueError(f"tree: the batch ({n}) must be a multiple of the device count ({n_dev}); use pad_batch")
    return jax.device_put(tree, sharding)


def sharded_vmap(
    fn: Callable,
    mesh: Mesh | None = None,
    *,
    in_axes: int | None | Sequence[int | None] = 0,
    method: str = "shard_map",
) -> Callable:
    """``jax.vmap(fn, in_axes)`` over the leading axis, split over the devices of ``mesh``.

    Positional arguments with ``in_axes`` 0 are batches (pytrees whose leaves share the leading
    axis); ``None`` arguments are broadcast to every item (replicated on every device). The batch
    is padded to a multiple of the device count (:func:`pad_batch`), split, run, gathered back
    and cut to its size, so the result equals ``jax.vmap(fn, in_axes)(*args)`` (equal to
    floating-point reassociation inside ``fn``; bit-equal for element-wise work). Outputs are
    batched along their leading axis. The compiled function is cached per input shape.

    method: ``"shard_map"`` (each device runs ``vmap(fn)`` on its slice; loops inside ``fn``
    stop per device) or ``"jit"`` (``jax.jit`` with the batch sharded in and out; XLA partitions).
    """
    if method not in ("shard_map", "jit"):
        raise ValueError(f"method: expected 'shard_map' or 'jit', got {method!r}")
    mesh = _mesh(mesh)
    axis = mesh.axis_names[0]
    cache: dict = {}

    def run(*args):
        axes = (in_axes,) * len(args) if not isinstance(in_axes, (list, tuple)) else tuple(in_axes)
        if len(axes) != len(args) or any(a not in (0, None) for a in axes):
            raise ValueError(f"in_axes: expected 0 or None for each of the {len(args)} arguments, got {in_axes!r}")
        batched = [i for i, a in enumerate(axes) if a == 0]
        if not batched:
            raise ValueError("in_axes: at least one argument must be batched (0)")
        sizes = {_batch_size(args[i], f"args[{i}]") for i in batched}
        if len(sizes) != 1:
            raise ValueError(f"args: batched arguments disagree on the batch size: {sorted(sizes)}")
        key = (axes, len(args))
        if key not in cache:
            cache[key] = _compile(fn, mesh, axis, axes, method)
        return cache[key](*args)

    return run


def _compile(fn, mesh, axis, axes, method):
    """One jitted function: pad the batch, constrain shardings, run, cut the padding off (one
    dispatch per call; padding and slicing eagerly would add a dispatch and a transfer each)."""
    vfn = jax.vmap(fn, in_axes=axes)
    batch_sh = NamedSharding(mesh, PartitionSpec(axis))
    rep_sh = NamedSharding(mesh, PartitionSpec())
    if method == "shard_map":
        spec = tuple(PartitionSpec(axis) if a == 0 else PartitionSpec() for a in axes)
        # check_vma=False: fn is arbitrary user code (solver loops over replicated settings),
        # and every output is batched, so there is nothing for the replication checker to prove.
        inner = jax.shard_map(
            vfn,
            mesh=mesh,
            in_specs=spec,
            out_specs=PartitionSpec(axis),
            check_vma=False,
        )
    else:
        inner = vfn

    def run(*args):
        n = _batch_size(args[axes.index(0)], f"args[{axes.index(0)}]")
        placed = []
        for a, ax in zip(args, axes):
            if ax == 0:
                a = pad_batch(a, mesh.size)[0]
            sh = batch_sh if ax == 0 else rep_sh
            placed.append(jax.tree_util.tree_map(lambda x, sh=sh: jax.lax.with_sharding_constraint(x, sh), a))
        out = inner(*placed)
        if method == "jit":
            out = jax.tree_util.tree_map(lambda x: jax.lax.with_sharding_constraint(x, batch_sh), out)
        return unpad_batch(out, n)

    return jax.jit(run)


def parse_devices(text: str) -> int | str:
    """A ``--devices`` value: ``"all"`` or a positive count (``ValueError`` naming ``devices``)."""
    if text == "all":
        return text
    try:
        count = int(text)
    except ValueError:
        count = 0
    if count < 1:
        raise ValueError(f"devices: expected 'all' or a positive count, got {text!r}")
    return count


@overload
def devices_mesh(devices: None = None) -> None: ...


@overload
def devices_mesh(devices: int | str | Sequence) -> Mesh: ...


def devices_mesh(devices: int | str | Sequence | None = None) -> Mesh | None:
    """The data mesh a ``devices`` option names: None (one device, no mesh), ``"all"`` (every
    device of every process), a count ``N`` (the first ``N`` of ``jax.devices()``; ``"N"`` too) or
    a sequence of devices. A count above the device count is a ValueError naming ``devices``."""
    if devices is None:
        return None
    if isinstance(devices, str):
        devices = parse_devices(devices)
        if devices == "all":
            return data_mesh()
    if isinstance(devices, (int, np.integer)):
        available = jax.devices()
        if not 1 <= devices <= len(available):
            raise ValueError(
                f"devices: expected 'all' or a count from 1 to the {len(available)} device(s) JAX sees, got {devices}"
            )
        return data_mesh(available[: int(devices)])
    return data_mesh(devices)


def check_batch_size(batch_size: int, mesh: Mesh | None, name: str = "batch_size") -> None:
    """ValueError naming ``name`` unless ``batch_size`` splits evenly over ``mesh``'s devices."""
    if mesh is not None and batch_size % _mesh(mesh).size:
        raise ValueError(
            f"{name}: {batch_size} does not divide over the {mesh.size} devices of the mesh; pick a multiple "
            f"of {mesh.size} (or fewer devices)"
        )


def __getattr__(name: str):
    if name == "solve_maps":  # moved: this module is generic and imports no method
        raise AttributeError(
            "jaxsem.parallel.solve_maps moved to jaxsem.slam.solve_maps (same arguments): jaxsem.parallel "
            "is the generic data-parallel layer and imports no method"
        )
    raise AttributeError(f"module 'jaxsem.parallel' has no attribute {name!r}")
