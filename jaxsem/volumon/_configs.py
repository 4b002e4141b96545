"""Training configs: one default (CPU-sized, VoluMon Both) and variants that change a few fields.

- :func:`default_config`: CPU-sized (MobileNetV2 width 0.35, 64 x 64 inputs, synthetic 128 x 96
  stereo images) -- trains to a useful model in minutes on a CPU.
- :func:`thesis_config`: the thesis' network (width 1.0, 224 x 224), batch 50, lr 1e-5 (section
  5.5.1): for a GPU.
- :func:`door_config`: the door model of section 5.8.1 (one class, absolute depth up to 15 m,
  eps_s = 0.1 m, alpha_y = 0.5 m) on rendered building doors (:mod:`jaxsem.mapping` 's door writer).
- :func:`get_config(variant, size)`: ``variant`` in :data:`VARIANTS` (Dual only, Primal only,
  Both, Both Noisy; section 5.5.1 weights) on top of ``size`` in ``("cpu", "thesis", "tiny")``
  (tiny: for tests).
"""

from __future__ import annotations

import dataclasses

from .._checks import check_fields
from ..config import Presets
from ..models import ReconstructionConfig, VoluMonConfig
from ._losses import LossConfig
from ._synthetic import SceneConfig

VARIANTS = ("dual", "primal", "both", "both_noisy", "oracle")
SIZES = ("cpu", "door", "fast", "lmo", "thesis", "tiny")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything :func:`jaxsem.volumon.train_and_evaluate` needs.

    Attributes:
      model, recon, loss, scene: sub-configs (network, eq. 5.7, eq. 5.8-5.14, synthetic data).
      variant: a name recorded with the results.
      noisy: box noise on the network input / f, clean box in the loss (Both Noisy).
      class_mode: multi-class head: "true" (row of the true class) or "expectation" (eq. 5.18).
      num_train: size of the training set (sample indices 0..num_train-1 of the train split).
      batch_size, num_steps, learning_rate: optax Adam settings.
      reset_optimizer_at: step at which the Adam state is re-initialised (thesis: halfway);
        None for never.
      augment: hue/saturation jitter and random erasing on the inputs (thesis 5.5.2).
      seed: PRNG seed of initialisation, data order, augmentation and the dataset.
      checkpoint_every, keep_checkpoints: orbax saves every K steps, keep the latest N.
      eval_every, num_eval: periodic evaluation on the held-out split every ``eval_every`` steps
        (0: only at the end) on ``num_eval`` samples (0: no evaluation).
      log_every: steps between logged loss lines.
      data: "device" (batches made inside the jitted step from a PRNG key, no host work),
        "host" (numpy generator indexed by (seed, index), ``num_train`` samples) or "directory"
        (a FAT-layout or ``make_synthetic`` directory, read by :mod:`jaxsem.volumon.data`; the command
        passes its batches to :func:`train_and_evaluate` as ``batch_fn``).
      data_dir: the directory of a ``data="directory"`` run (recorded with the config, so a
        resume on other data is refused); empty when a user's own ``batch_fn`` feeds the run
        (e.g. :class:`jaxsem.volumon.LabelBatch` batches), which needs no folder.
      class_names: the class list of a ``data="directory"`` run (class id = index; objects of
        other classes are skipped); empty: :data:`jaxsem.volumon.VOLUMON_CLASS_NAMES`.
    """

    model: VoluMonConfig = VoluMonConfig()
    recon: ReconstructionConfig = ReconstructionConfig()
    loss: LossConfig = LossConfig()
    scene: SceneConfig = SceneConfig()
    variant: str = "both"
    noisy: bool = False
    class_mode: str = "true"
    num_train: int = 2000
    batch_size: int = 32
    num_steps: int = 600
    learning_rate: float = 1e-3
    reset_optimizer_at: int | None = None
    augment: bool = True
    seed: int = 0
    checkpoint_every: int = 100
    keep_checkpoints: int = 3
    eval_every: int = 0
    num_eval: int = 128
    log_every: int = 10
    data: str = "device"
    data_dir: str = ""
    class_names: tuple[str, ...] = ()

    def __post_init__(self):
        if self.data not in ("device", "host", "directory"):
            raise ValueError(f"data: expected 'device', 'host' or 'directory', got {self.data!r}")
        if self.data_dir and self.data != "directory":
            raise ValueError(
                f"data_dir: expected no directory unless data == 'directory', got data={self.data!r}, "
                f"data_dir={self.data_dir!r}"
            )
        if self.class_mode not in ("true", "expectation"):
            raise ValueError(f"class_mode: expected 'true' or 'expectation', got {self.class_mode!r}")
        counts = ("num_train", "batch_size", "num_steps", "checkpoint_every", "keep_checkpoints", "log_every")
        check_fields(self, counts, "a positive int", lambda v: int(v) >= 1)
        if not self.learning_rate > 0:
            raise ValueError(f"learning_rate: expected > 0, got {self.learning_rate}")
        if self.class_names and len(self.class_names) != self.model.num_classes:
            raise ValueError(
                f"class_names: expected {self.model.num_classes} names (model.num_classes), got {list(self.class_names)}"
            )

    def replace(self, **changes) -> TrainConfig:
        return dataclasses.replace(self, **changes)

    def data_sizes(self) -> dict:
        """The sizes a directory's data is prepared at for this config: ``input_size`` and
        ``global_padding`` (the model's) and ``num_points`` (the scene's), as keyword arguments
        of :func:`jaxsem.volumon.data.volumon_eval_batch` and
        :func:`jaxsem.volumon.data.volumon_batch_source`."""
        return {
            "input_size": self.model.input_size,
            "global_padding": self.model.global_padding,
            "num_points": self.scene.num_points,
        }


def default_config() -> TrainConfig:
    """CPU-sized VoluMon Both: width 0.35, 64 x 64 inputs, 128 x 96 images (f = 110 px)."""
    scene = SceneConfig()
    recon = ReconstructionConfig(baseline_focal=scene.baseline * scene.focal, alpha_delta=30.0)
    # box errors in pixels (the thesis). With the primal size weight of eq. 5.12 read literally
    # (sqrt(d0 d1 d2)) this config divided them by 10 to keep the dual term near the primal term's
    # scale; with the default weight (d0 d1 d2, ~50 times larger at cracker-box sizes) plain pixels
    # give about the same balance (primal : dual ~15 : 1 on a trained Both network, was ~10 : 1).
    loss = LossConfig(pixel_scale=1.0)
    return TrainConfig(recon=recon, loss=loss, scene=scene)


def thesis_config() -> TrainConfig:
    """The thesis' network (MobileNetV2 width 1.0, 224 x 224), batch 50, lr 1e-5, optimiser reset
    halfway (section 5.5.1); images of FAT's size and focal length. For a GPU."""
    scene = SceneConfig(height=540, width=960, focal=768.16, depth_range=(0.5, 1.5), num_points=100)
    recon = ReconstructionConfig(baseline_focal=0.06 * 768.16, alpha_delta=150.0)
    return TrainConfig(
        model=VoluMonConfig(width_multiplier=1.0, input_size=224),
        recon=recon,
        loss=LossConfig(),
        scene=scene,
        batch_size=50,
        learning_rate=1e-5,
        num_steps=20000,
        reset_optimizer_at=10000,
        checkpoint_every=1000,
        eval_every=2000,
        num_eval=264,
    )


def tiny_config() -> TrainConfig:
    """For tests: a small CNN backbone (compiles in seconds), 32 x 32 inputs, 64 x 48 images."""
    base = default_config()
    return base.replace(
        model=VoluMonConfig(input_size=32, hidden=(32,), backbone="small_cnn"),
        scene=dataclasses.replace(base.scene, height=48, width=64, focal=55.0, num_points=16),
        recon=dataclasses.replace(base.recon, baseline_focal=0.06 * 55.0, alpha_delta=15.0),
        num_train=16,
        batch_size=4,
        num_steps=4,
        checkpoint_every=2,
        num_eval=0,
        log_every=1,
        augment=False,
        data="host",  # a fixed handful of indexed samples (the overfitting test); device data: data="device"
    )


def fast_config() -> TrainConfig:
    """The CPU preset the shipped model is trained with: four tabletop classes (cracker box, ball,
    melon, soup can, from :mod:`jaxsem.classes`) in one multi-class head, a small CNN backbone
    (width 24) on 48 x 48 inputs with the normalised box fed to the heads, the rotation head
    started with the shortest axis along the viewing ray, the primal distance along each point's
    viewing ray ("ray"), shape-aware losses (each class drawn with its own shape in the dual and
    primal terms): the fixes of the size collapse, see the model card. The shipped run used the
    radial distance for its first 1000 steps and a learning rate of 1e-4 from step 16000."""
    base = default_config()
    return base.replace(
        model=VoluMonConfig(
            input_size=48,
            hidden=(128,),
            num_classes=4,
            backbone="small_cnn",
            cnn_width=24,
            box_input=True,
            rotation_init="short_axis_along_ray",
        ),
        scene=dataclasses.replace(base.scene, classes=(0, 1, 2, 3)),
        loss=dataclasses.replace(base.loss, shape_aware=True, primal_distance="ray"),
        num_steps=20000,
        checkpoint_every=500,
        eval_every=500,
        num_eval=128,
        log_every=50,
    )


def door_config() -> TrainConfig:
    """The door model of thesis 5.8.1 on the CPU: :func:`fast_config` 's network with one class
    (``"door"`` of :mod:`jaxsem.classes`), the absolute depth parameterisation (``t_z`` from 0.5 to
    15 m; the thesis allowed 50 m in an office with longer sight lines than these buildings'),
    eps_s = 0.1 m and alpha_y = 0.5 m (the thesis' shape constants for doors), the box-shaped
    (shape-aware) dual loss. Use with ``variant="dual"`` (the thesis' Dual-Only: a doorway is
    negative space, so the primal loss has no surface to fit) on a directory of
    :func:`jaxsem.mapping.write_door_dataset`."""
    base = fast_config()
    return base.replace(
        model=dataclasses.replace(base.model, num_classes=1),
        recon=ReconstructionConfig(alpha_y=0.5, eps_s=0.1, depth_mode="absolute", min_depth=0.5, max_depth=15.0),
        scene=dataclasses.replace(base.scene, classes=(0,), num_points=16),
        class_names=("door",),
        num_steps=6000,
        checkpoint_every=250,
        eval_every=250,
        num_eval=100,
        log_every=25,
    )


#: The eight LM-O classes in class-row order (Linemod ids 1, 5, 6, 8, 9, 10, 11, 12), the class
#: list of :func:`lmo_config` (kept here so the config layer does not import the data layer; the
#: data layer's ``LMO_CLASS_NAMES`` is the same tuple).
LMO_CLASS_NAMES = ("ape", "can", "cat", "driller", "duck", "eggbox", "glue", "holepuncher")


def lmo_config() -> TrainConfig:
    """The LM-O model: :func:`fast_config` 's network (so it warm-starts from the shipped object
    model) with an eight-class head (:data:`LMO_CLASS_NAMES`), trained on rendered desk
    detections (``python -m jaxsem.volumon.data.make_lmo_renders``; ``data="directory"``, the folder of
    ``chunk_NNNN.npz``). Learning rate 1e-4 (a warm start), checkpoints every 250 steps, the
    evaluation every 250 steps on held-out renders."""
    base = fast_config()
    return base.replace(
        model=dataclasses.replace(base.model, num_classes=len(LMO_CLASS_NAMES)),
        class_names=LMO_CLASS_NAMES,
        learning_rate=1e-4,
        num_steps=3000,
        checkpoint_every=250,
        eval_every=250,
        num_eval=256,
        log_every=25,
    )


#: The sized presets (:class:`jaxsem.config.Presets`; "default" is "cpu"): :func:`get_config` puts a
#: variant's loss weights on one of them, or on a JSON file of fields over the default.
PRESETS: Presets[TrainConfig] = Presets(default_config)
PRESETS.register("cpu")(lambda c: c)
PRESETS.register("fast")(lambda c: fast_config())
PRESETS.register("thesis")(lambda c: thesis_config())
PRESETS.register("tiny")(lambda c: tiny_config())
PRESETS.register("door")(lambda c: door_config())
PRESETS.register("lmo")(lambda c: lmo_config())


def get_config(variant: str = "both", size: str = "cpu") -> TrainConfig:
    """A variant (section 5.5.1) of a sized preset.

    dual: alpha_D = 1, alpha_P = 0; primal: alpha_D = 0, alpha_P = 1; both: 1, 1; both_noisy:
    both with noisy input boxes. alpha_S = 100 in all (thesis). oracle: fully supervised on the
    3D labels (:func:`jaxsem.volumon._losses.oracle_loss_per_sample`; a diagnostic, not a VoluMon variant).
    Sizes: the presets of :data:`PRESETS` -- "cpu" (MobileNetV2 0.35, one class), "fast"
    (:func:`fast_config`), "door" (:func:`door_config`), "lmo" (:func:`lmo_config`), "thesis", "tiny" -- or a JSON file of :class:`TrainConfig` fields over
    the default (:func:`jaxsem.config.load`).
    """
    if size not in PRESETS.names and not str(size).endswith(".json"):
        raise ValueError(f"size: expected one of {sorted(SIZES)} or a .json file, got {size!r}")
    if variant not in VARIANTS:
        raise ValueError(f"variant: expected one of {VARIANTS}, got {variant!r}")
    cfg = PRESETS.resolve(size)
    weights = {
        "dual": (1.0, 0.0),
        "primal": (0.0, 1.0),
        "both": (1.0, 1.0),
        "both_noisy": (1.0, 1.0),
        "oracle": (0.0, 0.0),
    }[variant]
    loss = dataclasses.replace(cfg.loss, alpha_D=weights[0], alpha_P=weights[1])
    if variant == "oracle":
        loss = dataclasses.replace(loss, alpha_S=0.0, alpha_O=1.0)
    return cfg.replace(loss=loss, variant=variant, noisy=variant == "both_noisy")


def config_from_dict(d: dict) -> TrainConfig:
    """Inverse of ``dataclasses.asdict(TrainConfig)`` (e.g. the ``config.json`` of a training run)."""

    def tup(x):
        return tuple(tup(v) for v in x) if isinstance(x, list) else x

    sub = {"model": VoluMonConfig, "recon": ReconstructionConfig, "loss": LossConfig, "scene": SceneConfig}
    kw = {}
    for k, v in d.items():
        if k in sub:
            kw[k] = sub[k](**{kk: tup(vv) for kk, vv in v.items()})
        else:
            kw[k] = tup(v)
    return TrainConfig(**kw)
