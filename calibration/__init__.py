"""Calibration of rheological parameters (fitting, sensitivity, uncertainty); see docs/calibration.md.

* ``load_profiles`` / ``Profile`` (``calibration.data``): measured flume profiles, CSV or HDF5.
* ``ParameterSet`` / ``ParamSpec`` (``calibration.params``): which parameters are fitted, bounds, transforms.
* ``ProfileExperiment``, ``RunoutSeriesExperiment``, ``RestTimeExperiment`` (MPM runs: height
  profiles, front against time, repeated releases after rests), ``FlowCurveExperiment``,
  ``TransientExperiment``, ``ShearHistoryExperiment`` (rheometer: flow curve, constant-rate
  transients, rate steps and overshoot after rest), ``joint_loss`` (``calibration.experiments``).
* ``fit`` / ``FitResult`` (``calibration.fit``): Levenberg-Marquardt (optimistix), L-BFGS or Adam (optax)
  around one compiled model, multi-start.
* ``gauss_newton`` / ``Uncertainty`` (``calibration.uncertainty``): std, correlation, identifiability;
  ``numerical_uncertainty`` / ``combine``: the discretisation std from fits at several cell sizes.
* ``design`` (``calibration.design``): rank candidate measurements by D-optimal gain
  (``mpmjax design``); ``profile_likelihood`` (``calibration.profile``): likelihood-ratio intervals
  with the other parameters re-optimised (``mpmjax calibrate --profile``).
* ``fit_multilevel`` (``calibration.multilevel``): multi-fidelity fit, coarse cell size then finer ones.
* ``calibrate`` / ``CalibrationResult`` (``calibration.run``): the whole of ``mpmjax calibrate`` as one call
  (data, experiments, multilevel fit, uncertainty, fit.json and plots by ``calibration.report``).
* ``sweep`` (``calibration.sweep``): a parameter grid as one ``vmap`` batch, sharded over devices.
* the differentiable observables (height profile, smooth front, deposited volume), re-exported
  from ``mpmjax`` (``mpmjax._observables``), where the simulator's plots use them too.
"""

from mpmjax import deposited_volume, gaussian_kernel, height_profile, particle_volume, smooth_front

from .data import (
    DataError,
    Profile,
    RunoutSeries,
    ShearTest,
    load_profiles,
    load_rest_times,
    load_runout_series,
    load_shear_tests,
    write_profiles_csv,
)
from .experiments import (
    FlowCurveExperiment,
    ProfileExperiment,
    RestTimeExperiment,
    RunoutSeriesExperiment,
    ShearHistoryExperiment,
    TransientExperiment,
    joint_loss,
    overshoot_test,
)
from .design import (
    Candidate,
    DesignResult,
    ProfileRequest,
    design,
    flow_curve_candidate,
    profile_candidates,
    rheometer_candidate,
)
from .fit import FitResult, fit
from .multilevel import MultilevelResult, experiments_at_cell_size, fit_multilevel
from .params import DEFAULT_BOUNDS, ParameterSet, ParamSpec
from .profile import ParameterProfile, profile_likelihood
from .run import CalibrationResult, calibrate
from .sweep import sweep
from .uncertainty import NumericalUncertainty, Uncertainty, combine, gauss_newton, numerical_uncertainty

__all__ = [
    "DEFAULT_BOUNDS",
    "CalibrationResult",
    "Candidate",
    "DataError",
    "DesignResult",
    "FitResult",
    "FlowCurveExperiment",
    "MultilevelResult",
    "NumericalUncertainty",
    "ParamSpec",
    "ParameterProfile",
    "ParameterSet",
    "Profile",
    "ProfileExperiment",
    "ProfileRequest",
    "RestTimeExperiment",
    "RunoutSeries",
    "RunoutSeriesExperiment",
    "ShearHistoryExperiment",
    "ShearTest",
    "TransientExperiment",
    "Uncertainty",
    "calibrate",
    "combine",
    "deposited_volume",
    "design",
    "experiments_at_cell_size",
    "fit",
    "fit_multilevel",
    "flow_curve_candidate",
    "gauss_newton",
    "gaussian_kernel",
    "height_profile",
    "joint_loss",
    "load_profiles",
    "load_rest_times",
    "load_runout_series",
    "load_shear_tests",
    "numerical_uncertainty",
    "overshoot_test",
    "particle_volume",
    "profile_candidates",
    "profile_likelihood",
    "rheometer_candidate",
    "smooth_front",
    "sweep",
    "write_profiles_csv",
]
