"""ROSHAN object SLAM: problems, batch and online solvers, single-view initialisation.

Data structures (padded to capacity with masks, equinox pytrees): :class:`SlamProblem`,
:class:`SlamEstimate`, :class:`Frame`, :class:`Capacity`, :class:`NoiseModel`,
:class:`SolverConfig`. The residual functions and the class shape table are in
:mod:`jaxsem.factors`.

Solvers: :class:`SchurLevenbergMarquardt` (the structured LM as an optimistix solver, usable on
any residual function with pose and landmark blocks), :func:`solve_batch` (it, with the rescue of stranded objects; ``method="optimistix"``:
it on the tangent delta, differentiable by the implicit adjoint), :func:`solve_schur`, and the online smoother :func:`online_init` /
:func:`online_update` / :func:`online_estimate`. Every solver reports a :data:`RESULTS` code
(``throw=`` to raise instead); :func:`baseline_config` is the thesis' baseline.

A problem keeps the class table it was built with (``make_problem(..., classes=ClassTable)``,
:class:`jaxsem.classes.ClassTable`); odometry between consecutive poses is
``make_problem(..., odometry=...)`` (between factors, :func:`jaxsem.factors.between_residual`;
the batch solvers handle it, the online smoother does not yet). Objects without a depth
measurement start where their class size matches their box (``SolverConfig.depth_from_box``). :func:`box_init`
is the one single-view rule that :func:`initialize`, the online smoother and
:func:`jaxsem.slam.sim.solve_online`'s re-initialisation share.
"""

from ._batch import (
    SolveInfo as SolveInfo,
    damped_schur_step as damped_schur_step,
    damping_search as damping_search,
    default_strategy as default_strategy,
    levenberg_marquardt as levenberg_marquardt,
    roshan_solver as roshan_solver,
    solve_batch as solve_batch,
    solve_many as solve_many,
    solve_schur as solve_schur,
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
from ._cost import (
    Delta as Delta,
    Normal as Normal,
    box_health as box_health,
    box_rows as box_rows,
    first_order_object as first_order_object,
    first_order_pose as first_order_pose,
    linearize as linearize,
    pose_rows as pose_rows,
    prior_weight as prior_weight,
    residual_blocks as residual_blocks,
    retract as retract,
    retract_object as retract_object,
    retract_pose as retract_pose,
    support_rows as support_rows,
    total_cost as total_cost,
    upright_rows as upright_rows,
)
from ._draw import (  # figures of sequences and maps
    draw_camera_path as draw_camera_path,
    draw_overlay as draw_overlay,
    draw_top_down as draw_top_down,
)
from ._frontend import FrontEnd as FrontEnd, to_frame as to_frame  # OpenCV front end (thesis 4.5.1)
from ._frontend_types import (
    AssociatedDetection as AssociatedDetection,
    FrontEndConfig as FrontEndConfig,
    LandmarkEstimates as LandmarkEstimates,
)
from ._frontend_vision import hs_histogram as hs_histogram, triangulate_points as triangulate_points
from ._init import box_init as box_init, initialize as initialize
from ._map_json import map_to_json as map_to_json, truth_errors as truth_errors
from ._multistart import object_costs as object_costs, solve_yaw_starts as solve_yaw_starts
from ._online import (
    OnlineState as OnlineState,
    online_estimate as online_estimate,
    online_init as online_init,
    online_optimize as online_optimize,
    online_problem as online_problem,
    online_update as online_update,
)
from ._problem import (
    Capacity as Capacity,
    Frame as Frame,
    SlamEstimate as SlamEstimate,
    SlamProblem as SlamProblem,
    bucket_capacity as bucket_capacity,
    compact_boxes as compact_boxes,
    make_frame as make_frame,
    make_problem as make_problem,
    stack_problems as stack_problems,
)
from ._results import RESULTS as RESULTS, result_code as result_code, result_message as result_message
from ._run_sequence import (  # the online smoother over a sequence
    SequenceResult as SequenceResult,
    default_capacity as default_capacity,
    run_sequence as run_sequence,
)
from ._schur import (
    DampedSchurDescent as DampedSchurDescent,
    DampingSearch as DampingSearch,
    SchurLevenbergMarquardt as SchurLevenbergMarquardt,
    SchurStructure as SchurStructure,
    schur_normal as schur_normal,
)
from ._sequence import (  # sequence directories (JSON layout)
    load_image as load_image,
    load_sequence as load_sequence,
    noise_model as noise_model,
    save_sequence as save_sequence,
    sequence_from_simulation as sequence_from_simulation,
    sequence_to_json as sequence_to_json,
)
from ._sequence_checks import check_box as check_box  # a detection box against its image
from ._sequence_texture import (  # front end over a sequence
    measure_texture as measure_texture,
    support_height as support_height,
)
from ._sequence_types import Sequence as Sequence, SequenceFrame as SequenceFrame
from ._solve_maps import solve_maps as solve_maps  # a batch of maps over every device
from ._solver_config import (
    CostModel as CostModel,
    InitConfig as InitConfig,
    NoiseModel as NoiseModel,
    SolverConfig as SolverConfig,
    StoppingRule as StoppingRule,
    baseline_config as baseline_config,
)
from ._toy import frames_from_problem as frames_from_problem, toy_map as toy_map
from ._tum import TUM_INTRINSICS as TUM_INTRINSICS, load_tum_sequence as load_tum_sequence
