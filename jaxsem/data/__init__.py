"""Data: the Falling Things (FAT) layout loader, synthetic FAT-layout writers (primitives; textured
object meshes; doors of generated buildings), input pipelines.

Public names are re-exported from private modules; import them from here.
"""

from ._bop import (
    LINEMOD_NAMES as LINEMOD_NAMES,
    BopFrame as BopFrame,
    BopObject as BopObject,
    BopScene as BopScene,
    Mesh as Mesh,
    load_bop_scene as load_bop_scene,
    load_ply as load_ply,
    visible_boxes as visible_boxes,
)
from ._bop_eval import (
    BOP_SPLITS as BOP_SPLITS,
    LMO_TUNE_BELOW as LMO_TUNE_BELOW,
    bop_class_extents as bop_class_extents,
    bop_eval_batch as bop_eval_batch,
    bop_split_frames as bop_split_frames,
    load_bop_split as load_bop_split,
    read_rgb as read_rgb,
)
from ._bop_slam import (
    POSE_PRIOR_MODES as POSE_PRIOR_MODES,
    STRETCH_SETTINGS as STRETCH_SETTINGS,
    OdometryModel as OdometryModel,
    Spell as Spell,
    Stretch as Stretch,
    camera_from_anchors as camera_from_anchors,
    find_stretches as find_stretches,
    odometry_poses as odometry_poses,
    pose_prior_weights as pose_prior_weights,
    stretch_sequence as stretch_sequence,
    user_class_table as user_class_table,
)
from ._doors import (
    DOOR_BASELINE as DOOR_BASELINE,
    door_building as door_building,
    door_data_baseline as door_data_baseline,
    door_eval_batch as door_eval_batch,
    train_door_model as train_door_model,
    write_door_dataset as write_door_dataset,
)
from ._fat import (
    FAT_BASELINE as FAT_BASELINE,
    FAT_DEPTH_SCALE as FAT_DEPTH_SCALE,
    FAT_LENGTH_SCALE as FAT_LENGTH_SCALE,
    FatAnnotation as FatAnnotation,
    FatFormatError as FatFormatError,
    FatFrame as FatFrame,
    FatSequence as FatSequence,
    cuboid_corners as cuboid_corners,
    load_fat_annotations as load_fat_annotations,
    load_fat_frame as load_fat_frame,
    load_fat_scene as load_fat_scene,
    right_T_left as right_T_left,
)
from ._fetch import DATASETS as DATASETS, FetchError as FetchError, Source as Source, fetch as fetch
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
