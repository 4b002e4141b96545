"""ROSHAN's simulator: random ellipsoid maps, camera paths and noisy measurements (thesis 4.4).

The MuJoCo renderer is :mod:`jaxsem.data`'s; the rendered buildings are :mod:`jaxsem.mapping`'s.

Public names are re-exported from private modules; import them from here.
"""

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
