"""VoluMon's data: the FAT-layout input pipeline, the synthetic, textured-object and LM-O desk
writers and renders, the batch sources for training and the BOP evaluation batches.

- Inputs: :class:`VolumonDataset`, :class:`PipelineConfig` (:func:`thesis_config`),
  :func:`find_scenes`.
- Batch sources for training and evaluation: :func:`volumon_batch_source`,
  :func:`volumon_eval_batch`, :func:`desk_batch_source`, :func:`desk_eval_batch`.
- Writers: :func:`write_synthetic_dataset` (coloured primitives), :func:`write_object_dataset`
  (textured meshes), :func:`render_desk_frames` / :func:`write_desk_detections` (LM-O desks,
  :class:`DeskConfig`).
- Whole frames for the detect-and-lift network (:mod:`jaxsem.volumon.rcnn`): :func:`write_desk_frames`,
  :func:`load_frame_chunks`, :func:`bop_frames` (real photographs), :func:`frame_arrays`,
  :func:`frames_batch`, :func:`augment_batch` (the same frames seen by other cameras),
  :func:`jitter_batch` (their colours only), :func:`multiview_frames` (photographs paired for the
  dual loss).
- Real BOP scenes: :func:`load_bop_split`, :func:`bop_eval_batch`, :func:`bop_class_extents`,
  :func:`read_rgb`; the LM-O classes :data:`LMO_CLASS_NAMES`, :data:`LMO_CLASS_SHAPES`,
  :data:`LMO_OBJECT_IDS`, :func:`detections_from_frames`, :func:`is_desk_detections`,
  :func:`load_desk_detections`, :func:`load_lmo_meshes`.
- Object assets: :class:`ObjectClass`, :class:`ObjectAssets`, :class:`MeshAsset`,
  :func:`robosuite_assets`, :data:`ROBOSUITE_OBJECTS`, :func:`object_box`,
  :func:`face_color_atlas`, :exc:`ObjectAssetsMissingError`.

The building blocks (the pipeline's crops and batch conversion, the fixed BOP splits, the LM-O
camera, ...) stay importable from their private modules, e.g. ``jaxsem.volumon.data._pipeline``,
for tests and benchmarks.

Command-line writers: ``python -m jaxsem.volumon.data.make_synthetic``, ``make_objects``,
``make_lmo_renders``.
"""

from ._bop_eval import (
    bop_class_extents as bop_class_extents,
    bop_eval_batch as bop_eval_batch,
    load_bop_split as load_bop_split,
    read_rgb as read_rgb,
)
from ._desk_frames import (
    augment_batch as augment_batch,
    bop_frames as bop_frames,
    frame_arrays as frame_arrays,
    frames_batch as frames_batch,
    jitter_batch as jitter_batch,
    load_frame_chunks as load_frame_chunks,
    multiview_frames as multiview_frames,
    write_bop_scene as write_bop_scene,
    write_desk_frames as write_desk_frames,
)
from ._lmo_renders import (
    LMO_CLASS_NAMES as LMO_CLASS_NAMES,
    LMO_CLASS_SHAPES as LMO_CLASS_SHAPES,
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
    PipelineConfig as PipelineConfig,
    VolumonDataset as VolumonDataset,
    find_scenes as find_scenes,
    thesis_config as thesis_config,
)
from ._synthetic import (
    ObjectClass as ObjectClass,
    object_box as object_box,
    write_synthetic_dataset as write_synthetic_dataset,
)
from ._volumon_source import (
    volumon_batch_source as volumon_batch_source,
    volumon_eval_batch as volumon_eval_batch,
)
