"""LSD training and use: expert data, two-stage training, the planner's sampler (thesis ch. 3).

The network itself is :class:`jaxsem.models.LSDNet`; the planning world, the PRM and the online
loop are in :mod:`jaxsem.planning`.

What a user calls, by job:

- configs: :class:`TrainConfig`, :func:`get_config`, :data:`PRESETS`, :func:`default_config`,
  :func:`cpu_config`, :func:`tiny_config`;
- expert data (the shard schema :data:`EXPERT_SCHEMA`): :class:`ExpertConfig`,
  :func:`generate_expert_samples`, :func:`with_full_map`, :func:`write_expert_dataset`,
  :func:`load_expert_dataset`, :func:`load_expert_data`;
- training: :func:`train_and_evaluate` (both stages in one compiled step,
  :func:`make_two_stage_step` / :func:`two_stage_optimizer`; :func:`make_train_step` is one
  stage's step), :func:`load_trained`, :func:`export_model`;
- trained models and the planner's sampler: :func:`load_model`, :data:`PRETRAINED`,
  :data:`PRETRAINED_CPU`, :data:`PRETRAINED_CAMPUS`, :data:`PRETRAINED_HOUSE`,
  :class:`LSDSampler`, :func:`full_map_distribution`, :func:`full_map_sampler`;
- experiments: :func:`run_trials`, :func:`read_records`, :func:`summarise`,
  :func:`plot_success`, :func:`plot_navigation`.

The building blocks (augmentation, batching, the record schema, the stage optimizers, ...) stay
importable from their private modules, e.g. ``jaxsem.lsd._data``, for tests and benchmarks;
``ConfigMismatchError`` is :mod:`jaxsem.training`'s.
"""

from ._config import (
    PRESETS as PRESETS,
    TrainConfig as TrainConfig,
    cpu_config as cpu_config,
    default_config as default_config,
    get_config as get_config,
    tiny_config as tiny_config,
)
from ._data import load_expert_data as load_expert_data
from ._experiment import (
    plot_navigation as plot_navigation,
    plot_success as plot_success,
    read_records as read_records,
    run_trials as run_trials,
    summarise as summarise,
)
from ._expert import (
    ExpertConfig as ExpertConfig,
    __doc__ as EXPERT_SCHEMA,  # noqa: F401  (re-exported: the shard schema)
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
    PRETRAINED as PRETRAINED,
    PRETRAINED_CAMPUS as PRETRAINED_CAMPUS,
    PRETRAINED_CPU as PRETRAINED_CPU,
    PRETRAINED_HOUSE as PRETRAINED_HOUSE,
    export_model as export_model,
    load_model as load_model,
    load_trained as load_trained,
    make_train_step as make_train_step,
    make_two_stage_step as make_two_stage_step,
    train_and_evaluate as train_and_evaluate,
    two_stage_optimizer as two_stage_optimizer,
)
