"""Experiments and losses: what a calibration compares, and how.

An *experiment* turns material parameters into a vector of normalised residuals

    r_i = (model_i - data_i) / sigma_i

(``residuals(values)``, ``values``: name -> value of the calibrated parameters), and has a
weight w.  The calibration loss of several experiments fitted jointly is

    L = sum_e w_e mean_i(r_ei^2)

(dimensionless), i.e. each experiment contributes its mean squared normalised misfit,
so an experiment with many stations does not swamp one with a single runout.

* :class:`ProfileExperiment`: an MPM scene (``mpmjax.build``) against measured height
  profiles at given times, and optionally a measured runout.  The model height is
  ``mpmjax.height_profile`` (Gaussian kernel of bandwidth b, default one
  cell) at the data stations, at the saved frame nearest to each data time (a data time
  more than half a frame interval from every frame is an error); the model runout is
  ``smooth_front``.  sigma: the data's ``sigma_m`` where given, else ``sigma_m`` of the
  experiment (default: 5 % of the largest measured height, a typical flume-profile
  scatter); ``sigma_known`` tells the uncertainty analysis whether to trust it or to
  estimate the noise from the residuals.
* :class:`FlowCurveExperiment`: steady rheometer flow-curve points (any law with a steady
  state, ``mpmjax.rheometer.steady_flow_curve``), residual (ln tau_model - ln tau_data) /
  sigma_ln (relative error, default 5 %).
* :class:`TransientExperiment`: constant-shear rheometer transients mu(t) at k rates, each
  started from the law's initial internal state (``mpmjax.rheometer.constant_shear``),
  residual (ln mu_model - ln mu_data) / sigma_ln (default 5 %).

Any experiment works with any parameter set whose names are fields of its material.
"""

from __future__ import annotations

import math

import diffrax
import jax.numpy as jnp
import numpy as np

import mpmjax
from mpmjax import free_surface_front, height_profile, restate, smooth_front
from mpmjax.rheometer import constant_shear, steady_flow_curve, validate_params

from .data import Profile

__all__ = ["ProfileExperiment", "FlowCurveExperiment", "TransientExperiment", "joint_loss", "joint_residuals"]


class ProfileExperiment:
    """An MPM run compared with measured height profiles (and optionally the runout).

    setup: ``mpmjax.build(...)`` of the experiment's scene (its ``time.n_frames`` sets the
    frames that data times are matched to); profiles: list of :class:`calibration.data.Profile`
    (``t_s`` None = the final frame); bandwidth_m: kernel bandwidth b [m] (default: the
    cell size); sigma_m: profile standard deviation [m] where the data give none (default
    5 % of the largest measured height; then ``sigma_known`` is False unless set);
    runout_m / runout_sigma_m: a measured final runout [m] and its standard deviation
    [m] (default 2 cells), compared with the model's front: by default the headline runout's
    definition (``mpmjax.free_surface_front``: thickness >= 10 % of the model's thickest
    point, docs/output.md "Runout"), so a runout fitted here and the summary.json of a run
    measure the same thing; with ``front_threshold_m`` [m] given, ``smooth_front`` at that
    fixed thickness instead (for data measured at a known depth); weight: w.
    """

    def __init__(
        self,
        setup,
        profiles: list[Profile],
        *,
        bandwidth_m: float | None = None,
        sigma_m: float | None = None,
        sigma_known: bool | None = None,
        runout_m: float | None = None,
        runout_sigma_m: float | None = None,
        front_threshold_m: float | None = None,
        weight: float = 1.0,
        name: str = "profiles",
    ):
        if not profiles and runout_m is None:
            raise ValueError(f"{name}: no profile and no runout to compare with")
        self.setup, self.name, self.weight = setup, name, float(weight)
        sc = setup.scene
        if sc.dim != 2:
            raise ValueError(f"{name}: profile calibration is implemented for 2D scenes; got dim = {sc.dim}")
        self.profiles = list(profiles)
        lo, hi = sc.lo[0], sc.hi[0]
        for p in self.profiles:
            x = np.asarray(p.x_m, float)
            out = np.flatnonzero((x < lo) | (x > hi))
            if out.size:
                when = "final profile" if p.t_s is None else f"profile at t_s = {float(p.t_s):g} s"
                raise ValueError(
                    f"{name}: x_m = {float(x[out[0]]):g} (station {int(out[0]) + 1} of the {when}; "
                    f"{out.size} station(s) outside) lies outside the scene's domain: allowed range: "
                    f"{lo:g} .. {hi:g} m (domain.lo_m[0] .. domain.hi_m[0]); check the data's x origin and units"
                )
        frame_dt = sc.steps_per_frame * sc.dt
        self.frame_dt = frame_dt
        t_end = sc.n_frames * frame_dt
        idx, offsets = [], []
        for p in self.profiles:
            if p.t_s is None:
                k = sc.n_frames
            else:
                k = int(round(p.t_s / frame_dt))
                if p.t_s > t_end + 0.5 * frame_dt:
                    raise ValueError(
                        f"{name}: profile at t_s = {p.t_s:g} s is after the end of the scene's run "
                        f"(t_end = {t_end:g} s); allowed range: 0 .. {t_end:g} s (set time.t_end_s)"
                    )
            idx.append(k)
            offsets.append(k * frame_dt - (p.t_s if p.t_s is not None else t_end))
        self.frame_index = tuple(idx)
        self.time_offsets_s = tuple(offsets)
        hmax = max([float(np.max(p.h_m)) for p in self.profiles] or [0.0])
        if self.profiles and hmax <= 0:
            raise ValueError(f"{name}: every measured height is 0; nothing to fit")
        self.bandwidth_m = float(sc.h if bandwidth_m is None else bandwidth_m)
        if not self.bandwidth_m > 0:
            raise ValueError(f"{name}: bandwidth_m = {bandwidth_m}; allowed range: > 0 [m]")
        default_sigma = 0.05 * hmax if sigma_m is None else float(sigma_m)
        if self.profiles and not default_sigma > 0:
            raise ValueError(f"{name}: sigma_m = {sigma_m}; allowed range: > 0 [m]")
        self.sigma_known = (
            (sigma_m is not None or all(p.sigma_m is not None for p in self.profiles))
            if (sigma_known is None)
            else bool(sigma_known)
        )
        dt = jnp.dtype(sc.dtype)
        self._x = [jnp.asarray(p.x_m, dt) for p in self.profiles]
        self._h = [jnp.asarray(p.h_m, dt) for p in self.profiles]
        self._s = [
            jnp.asarray(p.sigma_m if p.sigma_m is not None else np.full(p.x_m.shape, default_sigma), dt)
            for p in self.profiles
        ]
        self.runout_m = None if runout_m is None else float(runout_m)
        self.runout_sigma_m = float(2 * sc.h if runout_sigma_m is None else runout_sigma_m)
        self.front_threshold_m = None if front_threshold_m is None else float(front_threshold_m)
        if self.runout_m is not None and self.front_threshold_m is not None and not self.front_threshold_m > 0:
            raise ValueError(f"{name}: front_threshold_m = {front_threshold_m}; allowed range: > 0 [m]")
        self.n_frames_needed = max(idx + [sc.n_frames if self.runout_m is not None else 0]) or 1
        self.n_residuals = sum(int(p.x_m.size) for p in self.profiles) + (self.runout_m is not None)

    # -- model -----------------------------------------------------------------------
    def material(self, values: dict):
        base = self.setup.params.material
        dt = jnp.dtype(self.setup.scene.dtype)
        bad = [k for k in values if k not in type(base)._fields]
        if bad:
            raise ValueError(f"{self.name}: {bad} are not fields of {type(base).__name__}")
        return base._replace(**{k: jnp.asarray(v, dt) for k, v in values.items()})

    def run(self, values: dict):
        """(initial state, frames) of the run with the material ``values`` (up to the last
        frame the data need)."""
        s = self.setup
        p = s.params._replace(material=self.material(values))
        st = restate(s.state, s.scene, p)
        _, fr = mpmjax.simulate(s.scene, st, p, self.n_frames_needed)
        return st, fr

    def _at(self, st, fr, k):
        if k == 0:
            return st.x, st.active
        return fr.x[k - 1], fr.active[k - 1]

    def model_profiles(self, values: dict):
        """List of model heights [m] at the data stations and times."""
        st, fr = self.run(values)
        out = []
        for k, x in zip(self.frame_index, self._x, strict=True):
            xp, act = self._at(st, fr, k)
            out.append(height_profile(xp, st.vol0, act, x, bandwidth=self.bandwidth_m))
        return out

    def _front(self, st, fr):
        sc = self.setup.scene
        xp, act = self._at(st, fr, self.setup.scene.n_frames)
        if self.front_threshold_m is None:
            return free_surface_front(xp, st.vol0, act, bandwidth=self.bandwidth_m, x_lo=sc.lo[0], x_hi=sc.hi[0])
        return smooth_front(
            xp,
            st.vol0,
            act,
            threshold_height=self.front_threshold_m,
            bandwidth=self.bandwidth_m,
            x_lo=sc.lo[0],
            x_hi=sc.hi[0],
            n_grid=max(200, int(4 * (sc.hi[0] - sc.lo[0]) / self.bandwidth_m)),
        )

    def residuals(self, values: dict):
        """Normalised residuals (model - data)/sigma: every profile station, then the
        runout if one is given."""
        st, fr = self.run(values)
        r = []
        for k, x, h, s in zip(self.frame_index, self._x, self._h, self._s, strict=True):
            xp, act = self._at(st, fr, k)
            r.append((height_profile(xp, st.vol0, act, x, bandwidth=self.bandwidth_m) - h) / s)
        if self.runout_m is not None:
            r.append(jnp.atleast_1d((self._front(st, fr) - self.runout_m) / self.runout_sigma_m))
        return jnp.concatenate(r)


def _rheometer_material(material, name):
    """Check a rheometer experiment's material: the parameters of a registered law, each in
    its declared range.  Returns its dtype."""
    try:
        mpmjax.law_of(material)
        validate_params(material)
    except ValueError as e:
        raise ValueError(f"{name}: {e}") from None
    return jnp.result_type(*material)


def _positive(name, field, a):
    bad = np.flatnonzero(~(np.isfinite(a) & (a > 0)))
    if bad.size:
        raise ValueError(f"{name}: {field}[{bad[0]}] = {float(a.flat[bad[0]])!r}; allowed range: > 0 and finite")


def _with(base, values: dict, dt):
    """``base`` with the fitted ``values`` (names that are not fields of it are ignored)."""
    return base._replace(**{k: jnp.asarray(v, dt) for k, v in values.items() if k in type(base)._fields})


class FlowCurveExperiment:
    """Steady rheometer flow curve: gamma_dot_1_s (m,) [1/s], tau_pa (m,) [Pa].

    material: any registered law's parameters whose law has a steady state (Coussot, or a
    law without internal variables).  Residual (ln tau_model - ln tau_data) / sigma_ln with
    sigma_ln the relative standard deviation of tau (default 0.05; ``sigma_known`` False
    unless given).  The model is ``mpmjax.rheometer.steady_flow_curve``; for Coussot it
    depends on alpha and T only through alpha*T.
    """

    def __init__(self, material, gamma_dot_1_s, tau_pa, *, sigma_ln=None, weight=1.0, name="flow curve"):
        g = np.asarray(gamma_dot_1_s, float)
        tau = np.asarray(tau_pa, float)
        if g.ndim != 1 or g.shape != tau.shape or g.size < 2:
            raise ValueError(f"{name}: gamma_dot_1_s {g.shape} and tau_pa {tau.shape} must be equal 1-D, >= 2 points")
        _positive(name, "gamma_dot_1_s", g)
        _positive(name, "tau_pa", tau)
        dt = _rheometer_material(material, name)
        try:
            steady_flow_curve(material, g[:1])
        except NotImplementedError as e:
            raise ValueError(f"{name}: no steady flow curve for {type(material).__name__}: {e}") from None
        self.base, self.name, self.weight = material, name, float(weight)
        self._g = jnp.asarray(g, dt)
        self._lt = jnp.log(jnp.asarray(tau, dt))
        self.sigma_ln = 0.05 if sigma_ln is None else float(sigma_ln)
        self.sigma_known = sigma_ln is not None
        self.n_residuals = g.size

    def residuals(self, values: dict):
        mat = _with(self.base, values, jnp.result_type(*self.base))
        tau, _ = steady_flow_curve(mat, self._g)
        return (jnp.log(tau) - self._lt) / self.sigma_ln


class TransientExperiment:
    """Constant-shear rheometer transients: t_s (m,) [s], gamma_dot_1_s (k,) [1/s], mu_pa_s
    (k, m) [Pa s]: k tests, test i at the constant rate gamma_dot_1_s[i] from t = 0, each
    started from the law's initial internal state (Coussot: lambda0).

    Residual (ln mu_model - ln mu_data) / sigma_ln, row by row (test by test), with sigma_ln
    the relative standard deviation of mu (default 0.05; ``sigma_known`` False unless given).
    The model is ``mpmjax.rheometer.constant_shear`` (Kvaerno5, tolerances ``rtol``/``atol``,
    default 1e-8/1e-10: model errors ~1e-7 in ln mu, far below any measurement's), with
    ``diffrax.DirectAdjoint`` so that both forward-mode (``calibration.fit``'s default for
    few parameters, ``gauss_newton``) and reverse-mode derivatives work.  For Coussot the
    relaxation rate alpha*gdot identifies alpha and the steady structure 1/(alpha T gdot)
    then T, which a flow curve cannot separate.
    """

    def __init__(
        self,
        material,
        t_s,
        gamma_dot_1_s,
        mu_pa_s,
        *,
        sigma_ln=None,
        weight=1.0,
        name="transient",
        rtol=1e-8,
        atol=1e-10,
        max_steps=4096,
    ):
        t = np.asarray(t_s, float)
        g = np.atleast_1d(np.asarray(gamma_dot_1_s, float))
        mu = np.asarray(mu_pa_s, float)
        if t.ndim != 1 or t.size < 1 or g.ndim != 1:
            raise ValueError(f"{name}: t_s {t.shape} and gamma_dot_1_s {g.shape} must be 1-D and non-empty")
        if mu.shape != (g.size, t.size):
            raise ValueError(f"{name}: mu_pa_s has shape {mu.shape}; expected (rates, times) = {(g.size, t.size)}")
        if not (np.all(np.isfinite(t)) and np.all(t >= 0) and np.all(np.diff(t) >= 0)):
            raise ValueError(f"{name}: t_s must be finite, >= 0 and non-decreasing [s]")
        bad = np.flatnonzero(~(np.isfinite(g) & (g >= 0)))
        if bad.size:
            raise ValueError(f"{name}: gamma_dot_1_s[{bad[0]}] = {float(g[bad[0]])!r}; allowed range: >= 0 and finite")
        _positive(name, "mu_pa_s", mu)
        dt = _rheometer_material(material, name)
        self.base, self.name, self.weight = material, name, float(weight)
        self._t = jnp.asarray(t, dt)
        self._g = jnp.asarray(g, dt)
        self._lmu = jnp.log(jnp.asarray(mu, dt))
        self.sigma_ln = 0.05 if sigma_ln is None else float(sigma_ln)
        self.sigma_known = sigma_ln is not None
        self.solver = {"rtol": float(rtol), "atol": float(atol), "max_steps": int(max_steps)}
        self.n_residuals = mu.size

    def model(self, values: dict):
        """Model viscosity mu [Pa s], (k, m), at the fitted ``values``."""
        mat = _with(self.base, values, jnp.result_type(*self.base))
        return constant_shear(mat, self._g, self._t, adjoint=diffrax.DirectAdjoint(), **self.solver).mu_pa_s

    def residuals(self, values: dict):
        return jnp.ravel((jnp.log(self.model(values)) - self._lmu) / self.sigma_ln)


def frames_for(times, t_end_default, n_frames_default):
    """(t_end, n_frames) so that every data time is a frame time when possible."""
    ts = [t for t in times if t is not None and t > 0]
    if not ts:
        return t_end_default, n_frames_default
    t_end = max(ts)
    for nf in range(1, 401):
        dtf = t_end / nf
        if all(abs(t / dtf - round(t / dtf)) < 1e-6 for t in ts):
            return t_end, max(nf, min(n_frames_default, 10 * nf) // nf * nf)
    return t_end, n_frames_default


def joint_residuals(experiments, values: dict):
    """List of residual vectors, one per experiment."""
    return [e.residuals(values) for e in experiments]


def joint_loss(experiments, values: dict):
    """L = sum_e w_e mean(r_e^2) (dimensionless)."""
    return sum(
        e.weight * jnp.mean(r**2) for e, r in zip(experiments, joint_residuals(experiments, values), strict=True)
    )


def check_finite_loss(value, where: str):
    v = float(value)
    if not math.isfinite(v):
        raise FloatingPointError(f"the loss is {v} at {where}: the run produced non-finite heights")
    return v
