"""VoluMon (thesis chapter 5): losses, inputs, synthetic data, training, refinement, evaluation.

What a user calls, by job:

- configs: :class:`TrainConfig`, :func:`get_config`, :func:`config_from_dict`, :data:`VARIANTS`,
  :data:`SIZES`, :data:`SHAPE_IDS`, :data:`VOLUMON_CLASS_NAMES`, :func:`model_class_names`,
  :func:`class_rows`;
- inputs and labels: :func:`prepare_inputs`, :func:`render_object_stereo`, :class:`LabelBatch`,
  :func:`label_batch`, :func:`make_batch`;
- training: :func:`train_and_evaluate`, :func:`make_train_step`, :class:`LossConfig`,
  :func:`volumon_loss`, :func:`warm_start_variables`;
- prediction and refinement: :func:`make_predict_fn`, :func:`predict_params`,
  :func:`predict_batch`, :func:`refine`, :func:`postopt`, :func:`optimise_from_scratch`,
  :class:`SingleViewEstimator`;
- evaluation: :func:`held_out_set`, :func:`evaluate_held_out`, :func:`evaluate_predictions`,
  :func:`evaluate_scene_batch`, :func:`summarise_detections`, :func:`evaluate_doors`,
  :func:`known_size_ellipsoid`, :data:`ORACLES`, :func:`draw_predictions`;
- trained models: :func:`load_pretrained`, :func:`load_trained`, :func:`export_pretrained`,
  :data:`PRETRAINED_DIR`, :data:`SHIPPED`.

The data pipelines are :mod:`jaxsem.volumon.data`'s; the detect-and-lift network (VoluMon
R-CNN, thesis 5.7) trains, loads (``rcnn.load_rcnn()``: the shipped LM-O model) and is scored
through :mod:`jaxsem.volumon.rcnn`. The building blocks (each loss term, the
device-side batches, the input crops, the presets, ...) stay importable from their private
modules, e.g. ``jaxsem.volumon._losses``, for tests and benchmarks; ``ConfigMismatchError`` is
:mod:`jaxsem.training`'s.
"""

from ._configs import (
    SIZES as SIZES,
    VARIANTS as VARIANTS,
    TrainConfig as TrainConfig,
    config_from_dict as config_from_dict,
    get_config as get_config,
)
from ._device_data import held_out_set as held_out_set
from ._door import SingleViewEstimator as SingleViewEstimator, evaluate_doors as evaluate_doors
from ._draw import draw_predictions as draw_predictions
from ._eval import evaluate_predictions as evaluate_predictions
from ._labels import (
    LabelBatch as LabelBatch,
    label_batch as label_batch,
)
from ._losses import LossConfig as LossConfig, volumon_loss as volumon_loss
from ._pretrained import (
    ORACLES as ORACLES,
    PRETRAINED_DIR as PRETRAINED_DIR,
    SHIPPED as SHIPPED,
    evaluate_held_out as evaluate_held_out,
    export_pretrained as export_pretrained,
    load_pretrained as load_pretrained,
    prepare_inputs as prepare_inputs,
)
from ._refine import (
    optimise_from_scratch as optimise_from_scratch,
    postopt as postopt,
    refine as refine,
)
from ._scene_eval import (
    class_rows as class_rows,
    evaluate_scene_batch as evaluate_scene_batch,
    known_size_ellipsoid as known_size_ellipsoid,
    model_class_names as model_class_names,
    summarise_detections as summarise_detections,
)
from ._synthetic import (
    SHAPE_IDS as SHAPE_IDS,
    VOLUMON_CLASS_NAMES as VOLUMON_CLASS_NAMES,
    make_batch as make_batch,
)
from ._train import (
    load_trained as load_trained,
    make_predict_fn as make_predict_fn,
    make_train_step as make_train_step,
    predict_batch as predict_batch,
    predict_params as predict_params,
    train_and_evaluate as train_and_evaluate,
    warm_start_variables as warm_start_variables,
)
from ._views import render_object_stereo as render_object_stereo
