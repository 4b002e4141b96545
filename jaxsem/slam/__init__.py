"""ROSHAN object SLAM: problems, batch and online solvers, single-view initialisation.

Data structures (padded to capacity with masks, equinox pytrees): :class:`SlamProblem`,
:class:`SlamEstimate`, :class:`Frame`, :class:`Capacity`, :class:`NoiseModel`,
:class:`SolverConfig`. The residual functions and the class shape table are in
:mod:`jaxsem.factors`.
"""

from ._problem import (
    Capacity as Capacity,
    Frame as Frame,
    NoiseModel as NoiseModel,
    SlamEstimate as SlamEstimate,
    SlamProblem as SlamProblem,
    SolverConfig as SolverConfig,
    make_frame as make_frame,
    make_problem as make_problem,
    stack_problems as stack_problems,
)
from ._frontend import (  # OpenCV front end for image sequences (thesis 4.5.1)
    AssociatedDetection as AssociatedDetection,
    FrontEnd as FrontEnd,
    FrontEndConfig as FrontEndConfig,
    LandmarkEstimates as LandmarkEstimates,
    hs_histogram as hs_histogram,
    to_frame as to_frame,
    triangulate_points as triangulate_points,
)
