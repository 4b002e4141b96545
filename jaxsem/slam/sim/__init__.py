"""ROSHAN's simulator: random ellipsoid maps, camera paths and noisy measurements (thesis 4.4).

The MuJoCo renderer is :mod:`jaxsem.data`'s; the rendered buildings are :mod:`jaxsem.mapping`'s.

Public names are re-exported from private modules; import them from here.

What a user calls, by job:

- configs: :class:`SimConfig`, :func:`thesis_config`, :func:`quadricslam_config`,
  :func:`class_table`, :func:`intrinsics`;
- maps and measurements: :func:`simulate`, :func:`simulate_batch`, :func:`simulate_views`,
  :class:`SimulatedMap`, and its draws :func:`random_objects`, :func:`camera_path`,
  :func:`detect`, :func:`perturb_poses`;
- into the solver: :func:`to_problem`, :func:`ground_truth`, :func:`initial_estimate`,
  :func:`sequence_from_simulation` (a simulated map as a sequence directory);
- experiments: the systems :data:`ROSHAN` and :data:`BASELINE`, :func:`solver_config`,
  :func:`solve_online`, :func:`map_errors`, :func:`truth_errors`, :func:`box_iou`.
"""

from .._map_json import truth_errors as truth_errors  # an estimated map against the simulated truth
from .._sequence import sequence_from_simulation as sequence_from_simulation  # a simulated map as a sequence directory
from ._ellipsoid_maps import (  # simulated maps, and into the solver's structures
    ground_truth as ground_truth,
    initial_estimate as initial_estimate,
    simulate as simulate,
    simulate_batch as simulate_batch,
    simulate_views as simulate_views,
    to_problem as to_problem,
)
from ._experiments import (
    BASELINE as BASELINE,
    ROSHAN as ROSHAN,
    box_iou as box_iou,
    map_errors as map_errors,
    solve_online as solve_online,
    solver_config as solver_config,
)
from ._sim_config import (  # the simulator's config, presets and map type
    SimConfig as SimConfig,
    SimulatedMap as SimulatedMap,
    class_table as class_table,
    intrinsics as intrinsics,
    quadricslam_config as quadricslam_config,
    thesis_config as thesis_config,
)
from ._sim_draws import (  # the random draws of a map
    camera_path as camera_path,
    detect as detect,
    perturb_poses as perturb_poses,
    random_objects as random_objects,
)
