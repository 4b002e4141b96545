"""Flax models: the LSD sampling-distribution network (and VoluMon).

What a user calls, by job:

- LSD (thesis ch. 3): :class:`LSDNet`, :class:`LSDConfig`, :class:`LSDOutput`, :func:`init_lsd`,
  :func:`encode_maps`, :func:`lsd_distribution`, :func:`lsd_nll`, :func:`path_cells_to_mask`,
  :func:`split_params` / :func:`is_context_param` (the two training stages), :func:`param_count`;
- VoluMon (thesis ch. 5): :class:`VoluMonNet`, :class:`VoluMonConfig`, :class:`VoluMonOutput`,
  :func:`init_volumon`, :class:`ReconstructionConfig`, :func:`reconstruct`,
  :func:`expected_params`, :func:`select_class_params`, :func:`box_features`, and the geometry it
  reconstructs with (:class:`Ellipsoid`, :func:`allocentric_rotation`, :func:`ray_rotation`, from
  :mod:`jaxsem.quadrics`);
- the backbone: :class:`MobileNetV2` (:func:`block_layout`, :func:`feature_dim`,
  :func:`last_channel`, :func:`make_divisible`), torchvision weights
  (:func:`convert_torchvision_mobilenet_v2`, :func:`load_backbone_into_volumon`);
- VoluMon R-CNN (thesis 5.7, detect and lift in one network): :class:`VoluMonRCNN`,
  :class:`RCNNConfig`, :func:`init_rcnn`, :class:`RCNNOutput`, :func:`detect` ->
  :class:`Detections`, :func:`detection_loss`, :func:`free_params`; the fixed-shape pieces it is
  built of: :func:`nms`, :func:`roi_align`.
"""

# the egocentric-allocentric rotations live in the geometry core; kept here under their old names
from ..quadrics import (
    Ellipsoid as Ellipsoid,  # VoluMon's outputs: the core's one type
    allocentric_rotation as allocentric_rotation,
    ray_rotation as ray_rotation,
)
from ._convert import (
    convert_torchvision_mobilenet_v2 as convert_torchvision_mobilenet_v2,
    load_backbone_into_volumon as load_backbone_into_volumon,
)
from ._detect import nms as nms, roi_align as roi_align
from ._lsd import (
    LSDConfig as LSDConfig,
    LSDNet as LSDNet,
    LSDOutput as LSDOutput,
    encode_maps as encode_maps,
    init_lsd as init_lsd,
    is_context_param as is_context_param,
    lsd_distribution as lsd_distribution,
    lsd_nll as lsd_nll,
    param_count as param_count,
    path_cells_to_mask as path_cells_to_mask,
    split_params as split_params,
)
from ._mobilenet import (
    MobileNetV2 as MobileNetV2,
    block_layout as block_layout,
    feature_dim as feature_dim,
    last_channel as last_channel,
    make_divisible as make_divisible,
)
from ._rcnn import (
    Detections as Detections,
    RCNNConfig as RCNNConfig,
    RCNNOutput as RCNNOutput,
    VoluMonRCNN as VoluMonRCNN,
    detect as detect,
    detection_loss as detection_loss,
    free_params as free_params,
    init_rcnn as init_rcnn,
)
from ._volumon import (
    ReconstructionConfig as ReconstructionConfig,
    VoluMonConfig as VoluMonConfig,
    VoluMonNet as VoluMonNet,
    VoluMonOutput as VoluMonOutput,
    box_features as box_features,
    expected_params as expected_params,
    init_volumon as init_volumon,
    reconstruct as reconstruct,
    select_class_params as select_class_params,
)
