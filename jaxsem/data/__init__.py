"""Data every method shares: the BOP and Falling Things (FAT) readers, the MuJoCo renderer, the
fetcher of real data sets.

- BOP scenes (LM-O and the like): :func:`load_bop_scene`, :func:`visible_boxes`, :func:`load_ply`.
- FAT-layout annotations and frames: :func:`load_fat_annotations`, :func:`load_fat_frame`,
  :func:`load_fat_scene`.
- Rendering (MuJoCo, loaded on first use): :class:`SceneRenderer`, :func:`render_views`;
  :class:`MujocoScene` is the lifecycle every MuJoCo scene of the package shares.
- Writing the FAT layout: :mod:`jaxsem.data.fat_writer` (what every FAT-layout writer shares).
- Real data: :func:`fetch` (``jaxsem data fetch``) and its table :data:`DATASETS`.

Each method's own data lives with the method: VoluMon's pipelines and writers in
:mod:`jaxsem.volumon.data`, ROSHAN's BOP sequences in :mod:`jaxsem.slam`, the rendered buildings
and doors in :mod:`jaxsem.mapping`. Their old names here still resolve for one release, with a
:class:`DeprecationWarning`.

The rest of the face, by job: BOP types :class:`BopScene`, :class:`BopFrame`,
:class:`BopObject`, :class:`Mesh`, :data:`LINEMOD_NAMES`; FAT types and constants
:class:`FatSequence`, :class:`FatFrame`, :class:`FatAnnotation`, :exc:`FatFormatError`,
:data:`FAT_BASELINE`, :data:`FAT_DEPTH_SCALE`, :data:`FAT_LENGTH_SCALE`, :func:`cuboid_corners`,
:func:`right_T_left`; the renderer's scene :class:`SceneObject`, :data:`SHAPES`,
:data:`RENDER_OUTPUTS`, :func:`bounding_ellipsoid_radii`, :func:`mujoco_intrinsics`,
:func:`mujoco_quaternion`, :func:`mujoco_view`; the fetcher's :class:`Source`, :exc:`FetchError`.
"""

from jaxsem._deprecated import moved_attribute as _moved_attribute

from . import fat_writer as fat_writer
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
from ._fetch import (
    DATASETS as DATASETS,
    FetchError as FetchError,
    Source as Source,
    fetch as fetch,
)
from ._render import (
    RENDER_OUTPUTS as RENDER_OUTPUTS,
    SHAPES as SHAPES,
    MujocoScene as MujocoScene,
    SceneObject as SceneObject,
    SceneRenderer as SceneRenderer,
    bounding_ellipsoid_radii as bounding_ellipsoid_radii,
    mujoco_intrinsics as mujoco_intrinsics,
    mujoco_quaternion as mujoco_quaternion,
    mujoco_view as mujoco_view,
    render_views as render_views,
)

# Names that moved to the method that uses them: name -> its new module (deprecated aliases).
_MOVED = {
    "BOP_SPLITS": "jaxsem.volumon.data._bop_eval",
    "DEFAULT_CLASSES": "jaxsem.volumon.data._synthetic",
    "DOOR_BASELINE": "jaxsem.mapping",
    "DeskConfig": "jaxsem.volumon.data",
    "LMO_CLASS_NAMES": "jaxsem.volumon.data",
    "LMO_CLASS_SHAPES": "jaxsem.volumon.data",
    "LMO_IMAGE_SIZE": "jaxsem.volumon.data._lmo_renders",
    "LMO_K": "jaxsem.volumon.data._lmo_renders",
    "LMO_OBJECT_IDS": "jaxsem.volumon.data",
    "LMO_TUNE_BELOW": "jaxsem.volumon.data._bop_eval",
    "MeshAsset": "jaxsem.volumon.data",
    "ObjectAssets": "jaxsem.volumon.data",
    "ObjectAssetsMissingError": "jaxsem.volumon.data",
    "ObjectClass": "jaxsem.volumon.data",
    "OdometryModel": "jaxsem.slam._bop_slam",
    "POSE_PRIOR_MODES": "jaxsem.slam._bop_slam",
    "PipelineConfig": "jaxsem.volumon.data",
    "ROBOSUITE_OBJECTS": "jaxsem.volumon.data",
    "SHAPE_IDS": "jaxsem.volumon.data._pipeline",
    "STRETCH_SETTINGS": "jaxsem.slam._bop_slam",
    "Spell": "jaxsem.slam._bop_slam",
    "Stretch": "jaxsem.slam._bop_slam",
    "VolumonDataset": "jaxsem.volumon.data",
    "as_volumon_batch": "jaxsem.volumon.data._pipeline",
    "bop_class_extents": "jaxsem.volumon.data",
    "bop_eval_batch": "jaxsem.volumon.data",
    "bop_split_frames": "jaxsem.volumon.data._bop_eval",
    "camera_from_anchors": "jaxsem.slam._bop_slam",
    "crop_inputs": "jaxsem.volumon.data._pipeline",
    "desk_batch_source": "jaxsem.volumon.data",
    "desk_eval_batch": "jaxsem.volumon.data",
    "detections_from_frames": "jaxsem.volumon.data",
    "door_building": "jaxsem.mapping",
    "door_data_baseline": "jaxsem.mapping",
    "door_eval_batch": "jaxsem.mapping",
    "face_color_atlas": "jaxsem.volumon.data",
    "find_scenes": "jaxsem.volumon.data",
    "find_stretches": "jaxsem.slam",
    "is_desk_detections": "jaxsem.volumon.data",
    "load_bop_split": "jaxsem.volumon.data",
    "load_desk_detections": "jaxsem.volumon.data",
    "load_distractor_meshes": "jaxsem.volumon.data._lmo_renders",
    "load_lmo_meshes": "jaxsem.volumon.data",
    "mask_depth_points": "jaxsem.volumon.data._pipeline",
    "object_box": "jaxsem.volumon.data",
    "odometry_poses": "jaxsem.slam._bop_slam",
    "pose_prior_weights": "jaxsem.slam._bop_slam",
    "read_rgb": "jaxsem.volumon.data",
    "render_desk_frames": "jaxsem.volumon.data",
    "robosuite_assets": "jaxsem.volumon.data",
    "stretch_sequence": "jaxsem.slam",
    "synthetic_intrinsics": "jaxsem.volumon.data._synthetic",
    "thesis_config": "jaxsem.volumon.data",
    "train_door_model": "jaxsem.mapping",
    "user_class_table": "jaxsem.slam",
    "volumon_batch_source": "jaxsem.volumon.data",
    "volumon_eval_batch": "jaxsem.volumon.data",
    "write_desk_detections": "jaxsem.volumon.data",
    "write_door_dataset": "jaxsem.mapping",
    "write_object_dataset": "jaxsem.volumon.data",
    "write_synthetic_dataset": "jaxsem.volumon.data",
}


def __getattr__(name):
    return _moved_attribute("jaxsem.data", _MOVED, name)
