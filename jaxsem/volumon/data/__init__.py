"""VoluMon's data: the FAT-layout input pipeline, the synthetic, textured-object and LM-O desk
writers and renders, the batch sources for training and the BOP evaluation batches.

- Inputs: :class:`VolumonDataset`, :func:`as_volumon_batch`, :func:`crop_inputs`,
  :class:`PipelineConfig` (:func:`thesis_config`), :func:`find_scenes`.
- Batch sources for training and evaluation: :func:`volumon_batch_source`,
  :func:`volumon_eval_batch`, :func:`desk_batch_source`, :func:`desk_eval_batch`.
- Writers: :func:`write_synthetic_dataset` (coloured primitives), :func:`write_object_dataset`
  (textured meshes), :func:`render_desk_frames` / :func:`write_desk_detections` (LM-O desks).
- Real BOP scenes: :func:`load_bop_split`, :func:`bop_eval_batch`, :func:`bop_class_extents`,
  the fixed splits :data:`BOP_SPLITS`.

Command-line writers: ``python -m jaxsem.volumon.data.make_synthetic``, ``make_objects``,
``make_lmo_renders``.
"""

from ._bop_eval import (
    BOP_SPLITS as BOP_SPLITS,
    LMO_TUNE_BELOW as LMO_TUNE_BELOW,
    bop_class_extents as bop_class_extents,
    bop_eval_batch as bop_eval_batch,
    bop_split_frames as bop_split_frames,
    load_bop_split as load_bop_split,
    read_rgb as read_rgb,
)
from ._lmo_renders import (
    LMO_CLASS_NAMES as LMO_CLASS_NAMES,
    LMO_CLASS_SHAPES as LMO_CLASS_SHAPES,
    LMO_IMAGE_SIZE as LMO_IMAGE_SIZE,
    LMO_K as LMO_K,
    LMO_OBJECT_IDS as LMO_OBJECT_IDS,
    DeskConfig as DeskConfig,
    desk_batch_source as desk_batch_source,
    desk_eval_batch as desk_eval_batch,
    detections_from_frames as detections_from_frames,
    face_color_atlas as face_color_atlas,
    is_desk_detections as is_desk_detections,
    load_desk_detections as load_desk_detections,
    load_distractor_meshes as load_distractor_meshes,
    load_lmo_meshes as load_lmo_meshes,
    render_desk_frames as render_desk_frames,
    write_desk_detections as write_desk_detections,
)
from ._objects import (
    ROBOSUITE_OBJECTS as ROBOSUITE_OBJECTS,
    MeshAsset as MeshAsset,
    ObjectAssets as ObjectAssets,
    ObjectAssetsMissingError as ObjectAssetsMissingError,
    robosuite_assets as robosuite_assets,
    write_object_dataset as write_object_dataset,
)
from ._pipeline import (
    SHAPE_IDS as SHAPE_IDS,
    PipelineConfig as PipelineConfig,
    VolumonDataset as VolumonDataset,
    as_volumon_batch as as_volumon_batch,
    crop_inputs as crop_inputs,
    find_scenes as find_scenes,
    mask_depth_points as mask_depth_points,
    thesis_config as thesis_config,
)
from ._synthetic import (
    DEFAULT_CLASSES as DEFAULT_CLASSES,
    ObjectClass as ObjectClass,
    object_box as object_box,
    synthetic_intrinsics as synthetic_intrinsics,
    write_synthetic_dataset as write_synthetic_dataset,
)
from ._volumon_source import (
    volumon_batch_source as volumon_batch_source,
    volumon_eval_batch as volumon_eval_batch,
)
