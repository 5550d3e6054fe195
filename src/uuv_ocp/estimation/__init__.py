"""State and current estimation: sensors as data, and estimators on the controller's own model.

:class:`~uuv_ocp.estimation.sensors.Sensors` says what is measured, how often and how noisily;
:class:`~uuv_ocp.estimation.base.Estimator` (``"ekf"``, ``"ukf"``, ``"mhe"``) estimates the state and the
ocean current from them on the problem's own discrete model (docs/estimation.md).
"""

from uuv_ocp.estimation.base import (
    SURVEY_CURRENT_FILTER,
    SURVEY_CURRENT_STD,
    Estimate,
    Estimator,
    EstimatorOptions,
    available_estimators,
    register_estimator,
)
from uuv_ocp.estimation.ekf import ExtendedKalmanFilter
from uuv_ocp.estimation.faults import (
    Detection,
    FaultDetectorOptions,
    StepFit,
    ThrusterFaultDetector,
    loss_regression,
    step_regression,
)
from uuv_ocp.estimation.mhe import MovingHorizonEstimator
from uuv_ocp.estimation.sensors import Measurement, Sensor, Sensors
from uuv_ocp.estimation.ukf import UnscentedKalmanFilter

__all__ = [
    "SURVEY_CURRENT_FILTER",
    "SURVEY_CURRENT_STD",
    "Detection",
    "FaultDetectorOptions",
    "ThrusterFaultDetector",
    "loss_regression",
    "StepFit",
    "step_regression",
    "Estimate",
    "Estimator",
    "EstimatorOptions",
    "ExtendedKalmanFilter",
    "Measurement",
    "MovingHorizonEstimator",
    "Sensor",
    "Sensors",
    "UnscentedKalmanFilter",
    "available_estimators",
    "register_estimator",
]
