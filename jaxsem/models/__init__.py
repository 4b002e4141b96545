"""Flax models: the LSD sampling-distribution network (and VoluMon)."""

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
