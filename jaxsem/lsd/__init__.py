"""LSD training and use: expert data, two-stage training, the planner's sampler (thesis ch. 3).

The network itself is :class:`jaxsem.models.LSDNet`; the planning world, the PRM and the online
loop are in :mod:`jaxsem.planning`.
"""

from ..training import ConfigMismatchError as ConfigMismatchError
from ._config import (
    PRESETS as PRESETS,
    TrainConfig as TrainConfig,
    cpu_config as cpu_config,
    default_config as default_config,
    get_config as get_config,
    tiny_config as tiny_config,
)
from ._data import (
    batch_indices as batch_indices,
    check_expert_data as check_expert_data,
    dihedral_augment as dihedral_augment,
    load_expert_data as load_expert_data,
    split_by_building as split_by_building,
)
from ._experiment import (
    ExperimentSetup as ExperimentSetup,
    format_table as format_table,
    merge_records as merge_records,
    plot_navigation as plot_navigation,
    plot_success as plot_success,
    prepare_model as prepare_model,
    read_records as read_records,
    run_trials as run_trials,
    summarise as summarise,
    trial_key as trial_key,
)
from ._expert import (
    SCHEMA_KEYS as SCHEMA_KEYS,
    ExpertConfig as ExpertConfig,
    __doc__ as EXPERT_SCHEMA,  # noqa: F401  (re-exported: the shard schema)
    full_map_state as full_map_state,
    generate_expert_samples as generate_expert_samples,
    load_expert_dataset as load_expert_dataset,
    with_full_map as with_full_map,
    write_expert_dataset as write_expert_dataset,
)
from ._sampler import (
    LSDSampler as LSDSampler,
    full_map_distribution as full_map_distribution,
    full_map_sampler as full_map_sampler,
)
from ._train import (
    MODELS as MODELS,
    PRETRAINED as PRETRAINED,
    PRETRAINED_CAMPUS as PRETRAINED_CAMPUS,
    PRETRAINED_CPU as PRETRAINED_CPU,
    PRETRAINED_HOUSE as PRETRAINED_HOUSE,
    RESUMABLE_FIELDS as RESUMABLE_FIELDS,
    STAGE_LABELS as STAGE_LABELS,
    TrainResult as TrainResult,
    evaluate_nll as evaluate_nll,
    export_model as export_model,
    load_model as load_model,
    load_model_file as load_model_file,
    load_trained as load_trained,
    make_train_step as make_train_step,
    make_two_stage_step as make_two_stage_step,
    save_distribution_figure as save_distribution_figure,
    stage_optimizer as stage_optimizer,
    train_and_evaluate as train_and_evaluate,
    two_stage_optimizer as two_stage_optimizer,
    warm_start_params as warm_start_params,
)
