"""Calibration of rheological parameters (fitting, sensitivity, uncertainty).

``calibration.observables``: differentiable observables of a run (height profile, smooth
front, deposited volume); see docs/calibration.md.
"""

from .observables import deposited_volume, gaussian_kernel, height_profile, particle_volume, smooth_front

__all__ = ["deposited_volume", "gaussian_kernel", "height_profile", "particle_volume", "smooth_front"]
