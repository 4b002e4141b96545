"""VoluMon (thesis chapter 5): losses, inputs, synthetic data, training, refinement, evaluation."""

from ..training import ConfigMismatchError as ConfigMismatchError
from ._configs import (
    LMO_CLASS_NAMES as LMO_CLASS_NAMES,
    PRESETS as PRESETS,
    SIZES as SIZES,
    VARIANTS as VARIANTS,
    TrainConfig as TrainConfig,
    config_from_dict as config_from_dict,
    default_config as default_config,
    door_config as door_config,
    get_config as get_config,
    lmo_config as lmo_config,
    thesis_config as thesis_config,
    tiny_config as tiny_config,
)
from ._device_data import (
    augmentation_numbers as augmentation_numbers,
    device_batch as device_batch,
    device_batch_jit as device_batch_jit,
    eval_key as eval_key,
    held_out_set as held_out_set,
    sample_scene as sample_scene,
    train_key as train_key,
)
from ._door import (
    SingleViewEstimator as SingleViewEstimator,
    door_errors as door_errors,
    evaluate_doors as evaluate_doors,
)
from ._draw import (
    box_corners_2d as box_corners_2d,
    draw_predictions as draw_predictions,
    ellipsoid_outline as ellipsoid_outline,
)
from ._eval import (
    cuboid_surface_points as cuboid_surface_points,
    detection_errors as detection_errors,
    evaluate_predictions as evaluate_predictions,
    size_errors as size_errors,
)
from ._inputs import (
    check_image_and_boxes as check_image_and_boxes,
    crop_and_resize as crop_and_resize,
    masked_global_image as masked_global_image,
    prepare_inputs as prepare_inputs,
    to_float_image as to_float_image,
)
from ._labels import (
    LabelBatch as LabelBatch,
    label_batch as label_batch,
)
from ._losses import (
    LossConfig as LossConfig,
    LossTerms as LossTerms,
    box_error as box_error,
    dual_loss as dual_loss,
    dual_loss_per_sample as dual_loss_per_sample,
    oracle_loss_per_sample as oracle_loss_per_sample,
    primal_loss as primal_loss,
    primal_loss_per_sample as primal_loss_per_sample,
    size_variance_loss as size_variance_loss,
    volumon_loss as volumon_loss,
)
from ._pretrained import (
    ORACLES as ORACLES,
    PRETRAINED_DIR as PRETRAINED_DIR,
    SHIPPED as SHIPPED,
    evaluate_held_out as evaluate_held_out,
    export_pretrained as export_pretrained,
    load_pretrained as load_pretrained,
    mean_size_radii as mean_size_radii,
)
from ._refine import (
    init_from_points as init_from_points,
    optimise_from_scratch as optimise_from_scratch,
    phi_from_ellipsoid as phi_from_ellipsoid,
    postopt as postopt,
    refine as refine,
)
from ._scene_eval import (
    CLASS_MAPPINGS as CLASS_MAPPINGS,
    VISIBILITY_BINS as VISIBILITY_BINS,
    class_rows as class_rows,
    evaluate_scene_batch as evaluate_scene_batch,
    known_size_ellipsoid as known_size_ellipsoid,
    model_class_names as model_class_names,
    summarise_detections as summarise_detections,
)
from ._synthetic import (
    CLASSES as CLASSES,
    SHAPE_IDS as SHAPE_IDS,
    VOLUMON_CLASS_NAMES as VOLUMON_CLASS_NAMES,
    SceneConfig as SceneConfig,
    make_batch as make_batch,
)
from ._train import (
    TRAIN_KEYS as TRAIN_KEYS,
    augment as augment,
    augmentation_params as augmentation_params,
    batch_indices as batch_indices,
    evaluate as evaluate,
    init_state as init_state,
    load_trained as load_trained,
    make_predict_fn as make_predict_fn,
    make_train_step as make_train_step,
    predict_batch as predict_batch,
    predict_params as predict_params,
    train_and_evaluate as train_and_evaluate,
    warm_start_variables as warm_start_variables,
)
from ._views import (
    StereoView as StereoView,
    render_object_stereo as render_object_stereo,
)
