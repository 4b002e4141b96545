"""The online smoother over a sequence: :func:`run_sequence` (frame by frame, with a callback), the
capacities that fit a sequence, and objects seeded from the sequence's initial ellipsoids.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import numpy as np

from .. import classes as _classes
from ..quadrics import EllipsoidView
from ._aot import exported
from ._online import _online_step, empty_frame, online_init, online_step
from ._problem import Capacity, make_frame
from ._sequence_types import Sequence
from ._solver_config import SolverConfig

# --------------------------------------------------------------------------------------------
# The online smoother over a sequence.


@dataclasses.dataclass(frozen=True)
class SequenceResult:
    """What :func:`run_sequence` returns (numpy).

    Attributes:
      object_ids: (J,) association ids; object_classes: (J,) class names.
      rotation (J, 3, 3), center (J, 3), radii (J, 3): the estimated ellipsoids.
      camera_T_world: (T, 4, 4) estimated pose of every frame (the latest estimate it had
        before it left the smoother's window, or the final one).
      frame_seconds: (T,) wall time of each ``online_update`` (the first includes compilation).
      state: the final :class:`jaxsem.slam._online.OnlineState`.
    """

    object_ids: tuple
    object_classes: tuple
    rotation: np.ndarray
    center: np.ndarray
    radii: np.ndarray
    camera_T_world: np.ndarray
    frame_seconds: np.ndarray
    state: Any = None

    ellipsoid = EllipsoidView()


def _bucket(n: int, step: int) -> int:
    return max(step, -(-int(n) // step) * step)


def default_capacity(sequence: Sequence, max_poses: int = 256):
    """A :class:`jaxsem.slam.Capacity` that fits ``sequence`` (sizes rounded up to buckets so that
    similar sequences share a compilation): every frame up to ``max_poses``, every object, the
    most detections of any frame."""
    T = len(sequence.frames)
    D = max([len(f.ids) for f in sequence.frames] + [1])
    J = max(len(sequence.object_ids), 1)
    P = min(_bucket(T, 16), max_poses)
    n_boxes = sum(len(f.ids) for f in sequence.frames)
    B = _bucket(min(n_boxes, P * D), 64)
    return Capacity(
        max_poses=P,
        max_objects=_bucket(J, 8),
        max_boxes=B,
        max_detections=_bucket(D, 4),
    )


def run_sequence(
    sequence: Sequence,
    config=None,
    *,
    capacity=None,
    optimize_every: int = 5,
    iterations: int = 3,
    final_iterations: int = 20,
    window: int | None = None,
    callback: Callable[[int, Any, float], None] | None = None,
    dtype=None,
    odometry: bool = False,
    prior_weights=None,
) -> SequenceResult:
    """Runs the online smoother (:func:`online_init`, then :func:`online_update` per frame).

    New association ids are initialised from their first detection (section 4.3.5), the graph is
    optimised every ``optimize_every`` frames, and after the last frame ``final_iterations``
    LM steps run over everything kept (0 skips it). Every frame and the final optimisation run
    one program (the online step); when JAX's persistent compilation cache is on, its traced
    form is kept in ``<cache dir>/jaxsem-exports`` so that later runs skip tracing
    (:mod:`jaxsem.slam._aot`).

    Args:
      sequence: :class:`Sequence`.
      config: :class:`jaxsem.slam.SolverConfig` (default: ROSHAN's defaults).
      capacity: :class:`jaxsem.slam.Capacity` (default :func:`default_capacity`); it must hold
        every object and the largest frame. The default follows the sequence, so each sequence
        of another size compiles its own program (several seconds on a CPU);
        to run many sequences, pass one capacity that holds them all.
      optimize_every, iterations, window, odometry, prior_weights: as
        :func:`jaxsem.slam.online_init` (``odometry=True, prior_weights=[[w_t, w_r], [0, 0]]``:
        the frames' poses read as integrated odometry, between factors along the chain and a
        prior on the first pose only, as the batch solve of such a sequence).
      callback: called after every frame as ``callback(index, state, seconds)``.
      dtype: float dtype (default: jax's default float).

    Returns:
      :class:`SequenceResult`.
    """
    if not isinstance(sequence, Sequence):
        raise ValueError(f"sequence: expected a Sequence (load_sequence), got {type(sequence).__name__}")
    config = SolverConfig() if config is None else config
    capacity = default_capacity(sequence) if capacity is None else capacity
    ids = sequence.object_ids
    slot = {i: j for j, i in enumerate(ids)}
    if len(ids) > capacity.max_objects:
        raise ValueError(f"capacity.max_objects: {capacity.max_objects} < {len(ids)} objects in the sequence")
    D_max = max(len(f.ids) for f in sequence.frames)
    if D_max > capacity.max_detections:
        raise ValueError(f"capacity.max_detections: {capacity.max_detections} < {D_max} detections in one frame")
    state = online_init(
        config,
        capacity,
        sequence.K,
        sequence.image_size,
        optimize_every=optimize_every,
        iterations=iterations,
        window=window,
        dtype=dtype,
        classes=sequence.classes,
        odometry=odometry,
        prior_weights=prior_weights,
    )
    # Committed to the device, as the step's outputs are: the traced program's call
    # (_aot.exported) compiles again for an argument that differs only in that.
    device = jax.devices()[0]
    state = jax.device_put(state, device)
    T, P = len(sequence.frames), capacity.max_poses
    poses = np.zeros((T, 4, 4))
    seconds = np.zeros(T)
    # Every frame and the final optimisation go through one program (_online_step: the
    # per-frame update and online_optimize in one), traced once per code version when the
    # compilation cache is on (_aot.exported keeps the traced program beside it), else once
    # per run.
    step = None
    update, final = np.asarray(False), np.asarray(True)
    no_steps = np.asarray(0, np.int32)
    pending = dict(sequence.initial or {})
    for t, fr in enumerate(sequence.frames):
        due = [i for i in fr.ids if i in pending]
        if due:  # user-given initial ellipsoids go in just before the object's first detection
            seeds = [(slot[i], fr.classes[fr.ids.index(i)], pending.pop(i)) for i in due]
            state = jax.device_put(_seed_objects(state, seeds), device)
        frame = make_frame(
            fr.camera_T_world,
            fr.boxes,
            list(fr.classes),
            [slot[i] for i in fr.ids],
            fr.texture_depth,
            max_detections=capacity.max_detections,
            max_objects=capacity.max_objects,
            dtype=state.problem.K.dtype,
            classes=sequence.classes,
            image_size=sequence.image_size,
        )
        start = time.perf_counter()
        if step is None:  # counted in the first frame's time
            step = exported("online_step", _online_step, (state, frame, update, no_steps), state)
        state = jax.block_until_ready(step(state, frame, update, no_steps))
        seconds[t] = time.perf_counter() - start
        if t + 1 >= P and t + 1 < T:  # the next frame reuses the slot of frame t + 1 - P
            poses[t + 1 - P] = np.asarray(state.estimate.camera_T_world)[(t + 1) % P]
        if callback is not None:
            callback(t, state, seconds[t])
    if final_iterations > 0:
        step = online_step if step is None else step
        state = step(state, empty_frame(state), final, np.asarray(final_iterations, np.int32))
    est = state.estimate
    pose_frame = np.asarray(state.pose_frame)
    cams = np.asarray(est.camera_T_world, np.float64)
    for s, t in enumerate(pose_frame):
        if 0 <= t < T:
            poses[t] = cams[s]
    J = len(ids)
    return SequenceResult(
        object_ids=ids,
        object_classes=sequence.object_classes,
        rotation=np.asarray(est.rotation, np.float64)[:J],
        center=np.asarray(est.center, np.float64)[:J],
        radii=np.asarray(est.radii, np.float64)[:J],
        camera_T_world=poses,
        frame_seconds=seconds,
        state=state,
    )


def _seed_objects(state, objects):
    """``state`` with objects ``(slot, class name, {"center", "radii", "rotation"})`` set as
    initialised (host-side arrays: no compile); their first detection then adds boxes only."""
    pb, est = state.problem, state.estimate
    table = _classes.as_table(pb.classes)
    arrays = {
        "object_mask": np.array(pb.object_mask),
        "object_class": np.array(pb.object_class),
        "rotation": np.array(est.rotation),
        "center": np.array(est.center),
        "radii": np.array(est.radii),
    }
    for j, cls, v in objects:
        arrays["object_mask"][j] = True
        arrays["object_class"][j] = table.index(cls)
        arrays["rotation"][j] = v["rotation"]
        arrays["center"][j] = v["center"]
        arrays["radii"][j] = v["radii"]
    put = {k: jax.device_put(a) for k, a in arrays.items()}
    return eqx.tree_at(
        lambda st: (
            st.problem.object_mask,
            st.problem.object_class,
            st.estimate.rotation,
            st.estimate.center,
            st.estimate.radii,
        ),
        state,
        (put["object_mask"], put["object_class"], put["rotation"], put["center"], put["radii"]),
    )
