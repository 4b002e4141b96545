"""ROSHAN object SLAM: problems, batch and online solvers, single-view initialisation.

Data structures (padded to capacity with masks, equinox pytrees): :class:`SlamProblem`,
:class:`SlamEstimate`, :class:`Frame`, :class:`Capacity`, :class:`NoiseModel`,
:class:`SolverConfig`. The residual functions and the class shape table are in
:mod:`jaxsem.factors`.

Solvers: :func:`solve_batch` (structured Schur LM by default; ``method="optimistix"`` for the
dense, differentiable one), :func:`solve_schur`, and the online smoother :func:`online_init` /
:func:`online_update` / :func:`online_estimate`. Every solver reports a :data:`RESULTS` code
(``throw=`` to raise instead); :func:`baseline_config` is the thesis' baseline.
"""

from ._batch import (
    SolveInfo as SolveInfo,
)
from ._batch import (
    damped_schur_step as damped_schur_step,
)
from ._batch import (
    damping_search as damping_search,
)
from ._batch import (
    levenberg_marquardt as levenberg_marquardt,
)
from ._batch import (
    solve_batch as solve_batch,
)
from ._batch import (
    solve_schur as solve_schur,
)
from ._cost import (
    Delta as Delta,
)
from ._cost import (
    Normal as Normal,
)
from ._cost import (
    box_health as box_health,
)
from ._cost import (
    linearize as linearize,
)
from ._cost import (
    residual_blocks as residual_blocks,
)
from ._cost import (
    retract as retract,
)
from ._cost import (
    total_cost as total_cost,
)
from ._frontend import (  # OpenCV front end for image sequences (thesis 4.5.1)
    AssociatedDetection as AssociatedDetection,
)
from ._frontend import (
    FrontEnd as FrontEnd,
)
from ._frontend import (
    FrontEndConfig as FrontEndConfig,
)
from ._frontend import (
    LandmarkEstimates as LandmarkEstimates,
)
from ._frontend import (
    hs_histogram as hs_histogram,
)
from ._frontend import (
    to_frame as to_frame,
)
from ._frontend import (
    triangulate_points as triangulate_points,
)
from ._init import initialize as initialize
from ._online import (
    OnlineState as OnlineState,
)
from ._online import (
    online_estimate as online_estimate,
)
from ._online import (
    online_init as online_init,
)
from ._online import (
    online_optimize as online_optimize,
)
from ._online import (
    online_problem as online_problem,
)
from ._online import (
    online_update as online_update,
)
from ._problem import (
    Capacity as Capacity,
)
from ._problem import (
    Frame as Frame,
)
from ._problem import (
    NoiseModel as NoiseModel,
)
from ._problem import (
    SlamEstimate as SlamEstimate,
)
from ._problem import (
    SlamProblem as SlamProblem,
)
from ._problem import (
    SolverConfig as SolverConfig,
)
from ._problem import (
    baseline_config as baseline_config,
    bucket_capacity as bucket_capacity,
)
from ._problem import (
    make_frame as make_frame,
)
from ._problem import (
    make_problem as make_problem,
)
from ._problem import (
    stack_problems as stack_problems,
)
from ._results import RESULTS as RESULTS
from ._results import result_code as result_code
from ._results import result_message as result_message
from ._sequence import (  # sequence directories (JSON layout), online runs over them, figures
    Sequence as Sequence,
)
from ._sequence import (
    SequenceFrame as SequenceFrame,
)
from ._sequence import (
    SequenceResult as SequenceResult,
)
from ._sequence import (
    default_capacity as default_capacity,
    noise_model as noise_model,
)
from ._sequence import (
    draw_camera_path as draw_camera_path,
)
from ._sequence import (
    draw_overlay as draw_overlay,
)
from ._sequence import (
    draw_top_down as draw_top_down,
)
from ._sequence import (
    load_image as load_image,
)
from ._sequence import (
    load_sequence as load_sequence,
)
from ._sequence import (
    map_to_json as map_to_json,
)
from ._sequence import (
    run_sequence as run_sequence,
)
from ._sequence import (
    save_sequence as save_sequence,
)
from ._sequence import (
    sequence_from_simulation as sequence_from_simulation,
)
from ._sequence import (
    sequence_to_json as sequence_to_json,
)
from ._sequence import (
    truth_errors as truth_errors,
)
from ._toy import frames_from_problem as frames_from_problem
from ._toy import toy_map as toy_map
