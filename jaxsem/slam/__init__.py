"""ROSHAN object SLAM: problems, batch and online solvers, single-view initialisation.

What a user calls, by job:

- problems (padded to capacity with masks, equinox pytrees): :class:`SlamProblem`,
  :class:`SlamEstimate`, :class:`Frame`, :class:`Capacity`, :func:`make_frame`,
  :func:`make_problem`, :func:`stack_problems`, :func:`toy_map`; :func:`bucket_capacities` (the
  padded sizes for many problems, at most a given number of compiled programs over them all); the solver's settings
  :class:`SolverConfig`, :func:`baseline_config` (the thesis' baseline), :func:`noise_model`;
- batch solvers: :func:`solve_batch` (structured Levenberg-Marquardt with the rescue of stranded
  objects; ``method="optimistix"``: differentiable by the implicit adjoint), :func:`solve_many`,
  :func:`solve_maps` (a batch of maps over every device), :class:`SchurLevenbergMarquardt` and
  :func:`roshan_solver` (the structured LM as an optimistix solver; its typed ``args`` and
  residual function are ``jaxsem.slam._cost.RoshanArgs`` and ``roshan_residuals``), :func:`result_message`
  (what a solver's result code means; ``throw=`` raises instead);
- the online smoother and single-view start: :func:`online_init`, :func:`online_update`,
  :func:`online_optimize`, :func:`online_estimate` (the graph it holds is ``state.problem``),
  :func:`run_sequence` (it over a sequence), :func:`initialize`;
- the cost: :func:`residual_blocks`, :func:`total_cost` (the factors are :mod:`jaxsem.factors`'s);
- sequences and the front end: :func:`load_sequence`, :func:`save_sequence`,
  :func:`load_tum_sequence` (a frame's image: ``sequence.image(t)``), :class:`FrontEndConfig`,
  :func:`measure_texture`, :func:`map_to_json`; a detector's output as tracks:
  :func:`associate_detections`, :func:`detected_sequence`;
- BOP sequences: :func:`find_stretches`, :func:`stretch_sequence`, :func:`user_class_table`;
- figures: :func:`draw_top_down`, :func:`draw_overlay`, :func:`draw_camera_path`.

A problem keeps the class table it was built with (``make_problem(..., classes=ClassTable)``,
:class:`jaxsem.classes.ClassTable`); odometry between consecutive poses is
``make_problem(..., odometry=...)`` (between factors, :func:`jaxsem.factors.between_residual`;
the batch solvers and ``online_init(..., odometry=True)`` handle it). Objects without a depth
measurement start where their class size matches their box (``SolverConfig.depth_from_box``).

The building blocks (the Schur solver's pieces, the cost's rows, retractions, result codes, the
OpenCV front end's classes, ...) stay importable from their private modules, e.g.
``jaxsem.slam._cost``, for tests and benchmarks.
"""

import warnings as _warnings

from ._associate import (  # a detector's output into tracks
    associate_detections as associate_detections,
    detected_sequence as detected_sequence,
)
from ._batch import (
    roshan_solver as roshan_solver,
    solve_batch as solve_batch,
    solve_many as solve_many,
)
from ._bop_slam import (
    find_stretches as find_stretches,
    stretch_sequence as stretch_sequence,
    user_class_table as user_class_table,
)
from ._cost import residual_blocks as residual_blocks, total_cost as total_cost
from ._draw import (  # figures of sequences and maps
    draw_camera_path as draw_camera_path,
    draw_overlay as draw_overlay,
    draw_top_down as draw_top_down,
)
from ._frontend_types import FrontEndConfig as FrontEndConfig
from ._init import initialize as initialize
from ._map_json import map_to_json as map_to_json
from ._online import (
    online_estimate as online_estimate,
    online_init as online_init,
    online_optimize as online_optimize,
    online_update as online_update,
)
from ._problem import (
    Capacity as Capacity,
    Frame as Frame,
    SlamEstimate as SlamEstimate,
    SlamProblem as SlamProblem,
    bucket_capacities as bucket_capacities,
    make_frame as make_frame,
    make_problem as make_problem,
    stack_problems as stack_problems,
)
from ._results import result_message as result_message
from ._run_sequence import run_sequence as run_sequence  # the online smoother over a sequence
from ._schur import SchurLevenbergMarquardt as SchurLevenbergMarquardt
from ._sequence import (  # sequence directories (JSON layout)
    load_image as _load_image,
    load_sequence as load_sequence,
    noise_model as noise_model,
    save_sequence as save_sequence,
)
from ._sequence_texture import measure_texture as measure_texture  # front end over a sequence
from ._solve_maps import solve_maps as solve_maps  # a batch of maps over every device
from ._solver_config import SolverConfig as SolverConfig, baseline_config as baseline_config
from ._toy import toy_map as toy_map
from ._tum import load_tum_sequence as load_tum_sequence


def __getattr__(name: str):
    # Names that left the face, for one release.
    if name == "load_image":
        _warnings.warn(
            "jaxsem.slam.load_image(sequence, t) is now the method sequence.image(t); "
            "the old name goes in the next release",
            DeprecationWarning,
            stacklevel=2,
        )
        return _load_image
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
