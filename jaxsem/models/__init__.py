"""Flax models: the LSD sampling-distribution network (and VoluMon)."""

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
