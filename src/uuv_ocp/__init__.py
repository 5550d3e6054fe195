"""uuv_ocp: optimal control of unmanned underwater vehicles with CasADi.

Problems are declared symbolically (:class:`Ocp`; :class:`TrackingProblem` is a UUV preset on
it), solved by any backend chosen by name (:func:`solve`, :func:`available_solvers`), judged by
one scorer (:func:`score`), and run in closed loop (:class:`NMPC`, :func:`simulate`).
Importing the package has no side effects: nothing is built, compiled or plotted.
"""

from uuv_ocp._version import __version__ as __version__
from uuv_ocp.control.disturbances import Current, GaussMarkov, MeasurementNoise
from uuv_ocp.control.dither import DitherOptions
from uuv_ocp.control.faults import RandomFaults, ThrusterFault
from uuv_ocp.control.guidance import GuidanceStep, LosGuidance, LosOptions
from uuv_ocp.control.mpc import NMPC, StepOutput, StepRecord
from uuv_ocp.control.simulation import ClosedLoopResult, Controller, SimulationInterrupted, simulate
from uuv_ocp.estimation import (
    Estimate,
    Estimator,
    EstimatorOptions,
    FaultDetectorOptions,
    Measurement,
    Sensor,
    Sensors,
    available_estimators,
    register_estimator,
)
from uuv_ocp.integrators import rk4_step
from uuv_ocp.judge import score
from uuv_ocp.model.base import VehicleLayout, VehicleModel
from uuv_ocp.model.fossen6dof import Vehicle6DOF
from uuv_ocp.model.planar import Vehicle
from uuv_ocp.model.remus100 import Remus100
from uuv_ocp.model.thrusters import ThrusterConfiguration
from uuv_ocp.native.runtime import GeneratedCode
from uuv_ocp.obstacles import Obstacle
from uuv_ocp.ocp import Ocp
from uuv_ocp.path_following import PathFollowingProblem, PathWeights, path_errors, path_metrics
from uuv_ocp.reference.path import PAPER_REFERENCES, Reference
from uuv_ocp.solvers import (
    Iterate,
    MinimizeResult,
    SolveResult,
    available_solvers,
    get_solver,
    minimize,
    new_solver,
    register_solver,
    register_swarm,
    solve,
)
from uuv_ocp.solvers.rti_export import generate_c
from uuv_ocp.studies.compare import compare, format_comparison
from uuv_ocp.tracking import TrackingProblem, Weights

__all__ = [
    "PAPER_REFERENCES",
    "ClosedLoopResult",
    "Controller",
    "Current",
    "Estimate",
    "Estimator",
    "EstimatorOptions",
    "DitherOptions",
    "FaultDetectorOptions",
    "GeneratedCode",
    "GaussMarkov",
    "GuidanceStep",
    "Iterate",
    "LosGuidance",
    "LosOptions",
    "MinimizeResult",
    "Measurement",
    "MeasurementNoise",
    "NMPC",
    "Obstacle",
    "Ocp",
    "PathFollowingProblem",
    "PathWeights",
    "Reference",
    "Remus100",
    "Sensor",
    "Sensors",
    "SimulationInterrupted",
    "SolveResult",
    "StepOutput",
    "StepRecord",
    "ThrusterConfiguration",
    "ThrusterFault",
    "RandomFaults",
    "TrackingProblem",
    "Vehicle",
    "Vehicle6DOF",
    "VehicleLayout",
    "VehicleModel",
    "Weights",
    "available_estimators",
    "available_solvers",
    "compare",
    "format_comparison",
    "generate_c",
    "get_solver",
    "new_solver",
    "path_errors",
    "path_metrics",
    "minimize",
    "register_estimator",
    "register_solver",
    "register_swarm",
    "rk4_step",
    "score",
    "simulate",
    "solve",
]
