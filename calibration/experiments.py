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
import jax
import jax.numpy as jnp
import numpy as np

import mpmjax
from mpmjax import free_surface_front, height_profile, restate, smooth_front
from mpmjax.rheometer import constant_shear, shear_history, steady_flow_curve, validate_params

from .data import Profile, ShearTest

__all__ = [
    "FlowCurveExperiment",
    "ProfileExperiment",
    "RestTimeExperiment",
    "RunoutSeriesExperiment",
    "ShearHistoryExperiment",
    "TransientExperiment",
    "joint_loss",
    "joint_residuals",
    "overshoot_test",
]


def _frame_indices(scene, times, name, what):
    """Frame index of each data time (None: the final frame) and its offset [s]; a time after
    the run's end (by more than half a frame interval) is a ValueError naming it."""
    frame_dt = scene.steps_per_frame * scene.dt
    t_end = scene.n_frames * frame_dt
    idx, offsets = [], []
    for t in times:
        if t is None:
            k = scene.n_frames
        else:
            k = int(round(t / frame_dt))
            if t > t_end + 0.5 * frame_dt:
                raise ValueError(
                    f"{name}: {what} at t_s = {t:g} s is after the end of the scene's run "
                    f"(t_end = {t_end:g} s); allowed range: 0 .. {t_end:g} s (set time.t_end_s)"
                )
        idx.append(k)
        offsets.append(k * frame_dt - (t if t is not None else t_end))
    return tuple(idx), tuple(offsets), frame_dt



def structure_after_rest(lambda_rest, rest_time_s, T):
    """Coussot structure [-] after ``rest_time_s`` [s] at rest from ``lambda_rest``: at zero shear
    rate dlambda/dt = 1/T, so lambda = lambda_rest + t_rest / T (differentiable in all three)."""
    return lambda_rest + rest_time_s / T

class _SceneExperiment:
    """What the MPM experiments share: the scene, the material at the fitted values (with the
    initial structure after a rest, ``rest_time_s``), the run, and the observables of a frame.

    Experiments with the same ``run_key`` (same setup and rest) share one run inside
    :func:`joint_residuals`: profiles and a runout series of one dam break cost one simulation.
    """

    def __init__(self, setup, *, name, weight, bandwidth_m=None, rest_time_s=None, lambda_rest=None):
        self.setup, self.name, self.weight = setup, name, float(weight)
        sc = setup.scene
        if sc.dim != 2:
            raise ValueError(f"{name}: profile calibration is implemented for 2D scenes; got dim = {sc.dim}")
        if not (math.isfinite(self.weight) and self.weight > 0):
            raise ValueError(f"{name}: weight = {weight!r}; allowed range: > 0 and finite")
        self.bandwidth_m = float(sc.h if bandwidth_m is None else bandwidth_m)
        if not self.bandwidth_m > 0:
            raise ValueError(f"{name}: bandwidth_m = {bandwidth_m}; allowed range: > 0 [m]")
        self.rest_time_s = None if rest_time_s is None else float(rest_time_s)
        self.lambda_rest = None if lambda_rest is None else float(lambda_rest)
        if self.rest_time_s is not None:
            fields = type(setup.params.material)._fields
            if not {"lambda0", "T"} <= set(fields):
                raise ValueError(
                    f"{name}: a rest time needs a material with structure aging (Coussot lambda0, T); "
                    f"got {type(setup.params.material).__name__}"
                )
            if not (math.isfinite(self.rest_time_s) and self.rest_time_s >= 0):
                raise ValueError(f"{name}: rest_time_s = {rest_time_s!r}; allowed range: >= 0 and finite [s]")
            if self.lambda_rest is not None and not (math.isfinite(self.lambda_rest) and self.lambda_rest >= 0):
                raise ValueError(f"{name}: lambda_rest = {lambda_rest!r}; allowed range: >= 0 and finite [-]")
        elif self.lambda_rest is not None:
            raise ValueError(f"{name}: lambda_rest is given without rest_time_s")

    @property
    def run_key(self):
        fresh = self.rest_time_s is None or (self.rest_time_s == 0 and self.lambda_rest is None)
        return (id(self.setup), None, None) if fresh else (id(self.setup), self.rest_time_s, self.lambda_rest)

    # -- model -----------------------------------------------------------------------
    def material(self, values: dict):
        """The material at the fitted ``values``; after a rest of t_rest, the initial structure
        is lambda_rest + t_rest / T (Coussot aging at rest, dlambda/dt = 1/T), lambda_rest
        defaulting to the material's lambda0, so T's (and lambda0's) gradient flows through it."""
        return self.params(values).material

    def params(self, values: dict):
        """The scene's ``Params`` at the fitted ``values`` (material and, on a depth-averaged
        scene's coulomb or voellmy terrain, basal friction), the structure after a rest applied
        as in :meth:`material`."""
        base = self.setup.params
        dt = jnp.dtype(self.setup.scene.dtype)
        try:
            p = mpmjax.replace_parameters(base, values, dt)
        except ValueError as e:
            raise ValueError(f"{self.name}: {e}") from None
        if self.rest_time_s is not None:
            mat = p.material
            lam = mat.lambda0 if self.lambda_rest is None else jnp.asarray(self.lambda_rest, dt)
            p = p._replace(material=mat._replace(lambda0=structure_after_rest(lam, self.rest_time_s, mat.T)))
        return p

    def run(self, values: dict, n_frames: int | None = None):
        """(initial state, frames) of the run with the parameter ``values`` (up to the last
        frame the data need, or ``n_frames``)."""
        s = self.setup
        p = self.params(values)
        st = restate(s.state, s.scene, p)
        _, fr = mpmjax.simulate(s.scene, st, p, self.n_frames_needed if n_frames is None else n_frames)
        return st, fr

    def _at(self, st, fr, k):
        """Positions, active mask and volumes of frame ``k`` (0: the initial state); the volumes are the
        frame's own (they change where the depth-averaged step splits columns)."""
        if k == 0:
            return st.x, st.active, st.vol0
        return fr.x[k - 1], fr.active[k - 1], st.vol0 if fr.vol0 is None else fr.vol0[k - 1]

    def _front(self, st, fr, k, front_threshold_m=None):
        sc = self.setup.scene
        xp, act, vol = self._at(st, fr, k)
        if front_threshold_m is None:
            return free_surface_front(xp, vol, act, bandwidth=self.bandwidth_m, x_lo=sc.lo[0], x_hi=sc.hi[0])
        return smooth_front(
            xp,
            vol,
            act,
            threshold_height=front_threshold_m,
            bandwidth=self.bandwidth_m,
            x_lo=sc.lo[0],
            x_hi=sc.hi[0],
            n_grid=max(200, int(4 * (sc.hi[0] - sc.lo[0]) / self.bandwidth_m)),
        )

    def residuals(self, values: dict):
        """Normalised residuals (model - data)/sigma."""
        return self.residuals_from(*self.run(values))


class ProfileExperiment(_SceneExperiment):
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
    fixed thickness instead (for data measured at a known depth); weight: w;
    rest_time_s / lambda_rest: the run starts after a rest (see :class:`RestTimeExperiment`).
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
        rest_time_s: float | None = None,
        lambda_rest: float | None = None,
    ):
        if not profiles and runout_m is None:
            raise ValueError(f"{name}: no profile and no runout to compare with")
        super().__init__(
            setup, name=name, weight=weight, bandwidth_m=bandwidth_m, rest_time_s=rest_time_s, lambda_rest=lambda_rest
        )
        sc = setup.scene
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
        idx, self.time_offsets_s, self.frame_dt = _frame_indices(sc, [p.t_s for p in self.profiles], name, "profile")
        self.frame_index = idx
        hmax = max([float(np.max(p.h_m)) for p in self.profiles] or [0.0])
        if self.profiles and hmax <= 0:
            raise ValueError(f"{name}: every measured height is 0; nothing to fit")
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
        self.n_frames_needed = max(list(idx) + [sc.n_frames if self.runout_m is not None else 0]) or 1
        self.n_residuals = sum(int(p.x_m.size) for p in self.profiles) + (self.runout_m is not None)

    def model_profiles(self, values: dict):
        """List of model heights [m] at the data stations and times."""
        st, fr = self.run(values)
        out = []
        for k, x in zip(self.frame_index, self._x, strict=True):
            xp, act, vol = self._at(st, fr, k)
            out.append(height_profile(xp, vol, act, x, bandwidth=self.bandwidth_m))
        return out

    def residuals_from(self, st, fr):
        """Normalised residuals (model - data)/sigma of the run (``st``, ``fr``): every profile
        station, then the runout if one is given."""
        r = []
        for k, x, h, s in zip(self.frame_index, self._x, self._h, self._s, strict=True):
            xp, act, vol = self._at(st, fr, k)
            r.append((height_profile(xp, vol, act, x, bandwidth=self.bandwidth_m) - h) / s)
        if self.runout_m is not None:
            front = self._front(st, fr, self.setup.scene.n_frames, self.front_threshold_m)
            r.append(jnp.atleast_1d((front - self.runout_m) / self.runout_sigma_m))
        return jnp.concatenate(r)


class RunoutSeriesExperiment(_SceneExperiment):
    """An MPM run compared with a measured front position against time.

    setup: ``mpmjax.build(...)`` (data times are matched to its frames as for profiles);
    t_s (m,) [s]: the times, >= 0 (0 is the initial frame); x_front_m (m,) [m]: the measured
    front position in the scene's x coordinates (the profiles' origin); sigma_m: its standard
    deviation [m], a scalar or (m,) (default 2 cells; ``sigma_known`` False unless given).
    The model front is the headline runout's definition, ``mpmjax.free_surface_front``
    (thickness >= 10 % of the frame's thickest point, kernel bandwidth ``bandwidth_m``,
    default one cell; docs/output.md "Runout"), at every data time.
    rest_time_s / lambda_rest: the run starts after a rest (see :class:`RestTimeExperiment`).
    """

    def __init__(
        self,
        setup,
        t_s,
        x_front_m,
        *,
        sigma_m=None,
        sigma_known: bool | None = None,
        bandwidth_m: float | None = None,
        weight: float = 1.0,
        name: str = "runout series",
        rest_time_s: float | None = None,
        lambda_rest: float | None = None,
    ):
        super().__init__(
            setup, name=name, weight=weight, bandwidth_m=bandwidth_m, rest_time_s=rest_time_s, lambda_rest=lambda_rest
        )
        sc = setup.scene
        t = np.atleast_1d(np.asarray(t_s, float))
        xf = np.atleast_1d(np.asarray(x_front_m, float))
        if t.ndim != 1 or t.size < 1 or xf.shape != t.shape:
            raise ValueError(f"{name}: t_s {t.shape} and x_front_m {xf.shape} must be equal 1-D, >= 1 point")
        bad = np.flatnonzero(~(np.isfinite(t) & (t >= 0)))
        if bad.size:
            raise ValueError(f"{name}: t_s[{bad[0]}] = {float(t[bad[0]])!r}; allowed range: >= 0 and finite [s]")
        bad = np.flatnonzero(~(np.isfinite(xf) & (xf >= sc.lo[0]) & (xf <= sc.hi[0])))
        if bad.size:
            raise ValueError(
                f"{name}: x_front_m[{bad[0]}] = {float(xf[bad[0]])!r}; allowed range: {sc.lo[0]:g} .. {sc.hi[0]:g} m "
                "(the scene's domain along x)"
            )
        s = np.broadcast_to(np.asarray(2 * sc.h if sigma_m is None else sigma_m, float), t.shape)
        bad = np.flatnonzero(~(np.isfinite(s) & (s > 0)))
        if bad.size:
            raise ValueError(f"{name}: sigma_m[{bad[0]}] = {float(s[bad[0]])!r}; allowed range: > 0 and finite [m]")
        self.frame_index, self.time_offsets_s, self.frame_dt = _frame_indices(sc, list(t), name, "front position")
        self.sigma_known = (sigma_m is not None) if sigma_known is None else bool(sigma_known)
        dt = jnp.dtype(sc.dtype)
        self.t_s, self.x_front_m, self.sigma_m = t, xf, np.array(s)
        self._xf, self._s = jnp.asarray(xf, dt), jnp.asarray(s, dt)
        self.n_frames_needed = max(self.frame_index) or 1
        self.n_residuals = int(t.size)

    def model_fronts(self, values: dict):
        """Model front positions [m] at the data times."""
        return self.fronts_from(*self.run(values))

    def fronts_from(self, st, fr):
        return jnp.stack([self._front(st, fr, k) for k in self.frame_index])

    def residuals_from(self, st, fr):
        return (self.fronts_from(st, fr) - self._xf) / self._s


class RestTimeExperiment:
    """Repeated dam breaks after different rest times: the same scene released after resting
    t_rest, each run compared with its measured front positions against time.

    At rest the Coussot structure builds at dlambda/dt = 1/T (the kinetics at zero shear rate),
    so a run after a rest of t_rest starts from lambda_init = lambda_rest + t_rest / T: with T
    traced, its gradient flows through the initial state.  lambda_rest is the structure when the
    rest began: by default the material's lambda0 (fitted or fixed: every release starts from
    the same prepared state and then rests), or a given value (e.g. the structure at the end of
    the previous flow, measured or computed).

    runs: list of (rest_time_s [s], t_s (m,) [s], x_front_m (m,) [m], sigma_m [m] scalar,
    (m,) or None); each becomes a :class:`RunoutSeriesExperiment` with that rest time.
    Residuals: every run's, in order.  sigma_m where a run gives none: ``sigma_m`` (default
    2 cells; ``sigma_known`` False unless a sigma is given).
    """

    def __init__(
        self,
        setup,
        runs,
        *,
        sigma_m=None,
        sigma_known: bool | None = None,
        bandwidth_m: float | None = None,
        lambda_rest: float | None = None,
        weight: float = 1.0,
        name: str = "rest times",
    ):
        if not runs:
            raise ValueError(f"{name}: no run to compare with")
        self.setup, self.name, self.weight = setup, name, float(weight)
        self.runs = []
        for tr, t, xf, s in runs:
            self.runs.append(
                RunoutSeriesExperiment(
                    setup,
                    t,
                    xf,
                    sigma_m=s if s is not None else sigma_m,
                    sigma_known=(s is not None or sigma_m is not None) if sigma_known is None else sigma_known,
                    bandwidth_m=bandwidth_m,
                    weight=weight,
                    name=f"{name} (rest {float(tr):g} s)",
                    rest_time_s=tr,
                    lambda_rest=lambda_rest,
                )
            )
        self.rest_times_s = tuple(r.rest_time_s for r in self.runs)
        if len(set(self.rest_times_s)) != len(self.rest_times_s):
            raise ValueError(f"{name}: rest times {self.rest_times_s} repeat; give each rest time once")
        self.sigma_known = all(r.sigma_known for r in self.runs)
        self.n_residuals = sum(r.n_residuals for r in self.runs)
        self.n_frames_needed = max(r.n_frames_needed for r in self.runs)

    def model_fronts(self, values: dict):
        """Per run, the model front positions [m] at its data times."""
        return [r.model_fronts(values) for r in self.runs]

    def residuals(self, values: dict):
        return jnp.concatenate([r.residuals(values) for r in self.runs])


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


class ShearHistoryExperiment:
    """Rheometer tests under piecewise-constant shear rates: stress responses to shear-rate
    steps, and the stress overshoot at start-up after a rest (pre-shear, rest, shear).

    tests: list of :class:`calibration.data.ShearTest` (each from the law's initial internal
    state at t = 0; a rest is a rate-0 stretch, during which Coussot structure builds at 1/T,
    so the stress at the next start-up overshoots its steady value and relaxes at alpha*gdot).
    Residual (ln tau_model - ln tau_data) / sigma_ln at every row with a measured stress, test
    by test; sigma_ln: the tests' own values where given, else ``sigma_ln`` (default 0.05;
    ``sigma_known`` False unless one was given).  The model is
    ``mpmjax.rheometer.shear_history`` (Kvaerno5, tolerances ``rtol``/``atol``; the rate
    steps are ``jump_ts``) with ``diffrax.DirectAdjoint`` (forward and reverse mode), and tau
    = law.mu(gdot_i, internal(t_i)) gdot_i at each row's rate.  For Coussot the overshoot's
    height after rests of different lengths measures T, its decay rate alpha, and the steady
    stresses at several rates mu0, n and alpha*T.
    """

    def __init__(
        self, material, tests, *, sigma_ln=None, weight=1.0, name="shear history", rtol=1e-8, atol=1e-10,
        max_steps=4096,
    ):
        if not tests:
            raise ValueError(f"{name}: no rheometer test")
        dt = _rheometer_material(material, name)
        if not (math.isfinite(float(weight)) and float(weight) > 0):
            raise ValueError(f"{name}: weight = {weight!r}; allowed range: > 0 and finite")
        if sigma_ln is not None and not (math.isfinite(float(sigma_ln)) and float(sigma_ln) > 0):
            raise ValueError(f"{name}: sigma_ln = {sigma_ln!r}; allowed range: > 0 and finite [-]")
        self.base, self.name, self.weight = material, name, float(weight)
        self.tests = list(tests)
        default = 0.05 if sigma_ln is None else float(sigma_ln)
        self.sigma_known = sigma_ln is not None or all(t.sigma_ln is not None for t in self.tests)
        self.solver = {"rtol": float(rtol), "atol": float(atol), "max_steps": int(max_steps)}
        self._data = []
        for t in self.tests:
            fit_rows = np.flatnonzero(np.isfinite(np.asarray(t.tau_pa, float)))
            s = np.broadcast_to(np.asarray(default if t.sigma_ln is None else t.sigma_ln, float), t.t_s.shape)
            times, rates = t.schedule()
            self._data.append(
                tuple(
                    np.asarray(a, float)
                    for a in (
                        times,
                        rates,
                        np.asarray(t.t_s, float)[fit_rows],
                        np.asarray(t.gamma_dot_1_s, float)[fit_rows],
                        np.log(np.asarray(t.tau_pa, float)[fit_rows]),
                        s[fit_rows],
                    )
                )
            )
        # tests of the same shape (schedule steps, measured rows) are one vmap batch: one solve
        # compiled per shape, not per test
        groups = {}
        for i, d in enumerate(self._data):
            groups.setdefault((d[0].size, d[2].size), []).append(i)
        self._groups = [(idx, [jnp.asarray(np.stack([self._data[i][j] for i in idx]), dt) for j in range(4)])
                        for idx in groups.values()]
        self._ln_tau = jnp.asarray(np.concatenate([d[4] for d in self._data]), dt)
        self._sigma = jnp.asarray(np.concatenate([d[5] for d in self._data]), dt)
        self.n_residuals = int(self._ln_tau.size)

    def model(self, values: dict):
        """Model shear stress tau [Pa] at every measured row, one array per test."""
        mat = _with(self.base, values, jnp.result_type(*self.base))
        law = mpmjax.law_of(mat)()

        def one(times, rates, ts, g):
            r = shear_history(mat, times, rates, ts, adjoint=diffrax.DirectAdjoint(), **self.solver)
            return law.mu(mat, g, r.internal) * g

        out = [None] * len(self._data)
        for idx, arrays in self._groups:
            tau = jax.vmap(one)(*arrays)
            for k, i in enumerate(idx):
                out[i] = tau[k]
        return out

    def residuals(self, values: dict):
        return (jnp.log(jnp.concatenate(self.model(values))) - self._ln_tau) / self._sigma


def overshoot_test(label, *, preshear_1_s, preshear_s, rest_s, rate_1_s, t_after_s, tau_pa=None, sigma_ln=None):
    """The rows of a stress-overshoot test as a :class:`calibration.data.ShearTest`: pre-shear
    at ``preshear_1_s`` [1/s] for ``preshear_s`` [s] (erasing the initial structure), rest for
    ``rest_s`` [s] (structure builds), then shear at ``rate_1_s`` [1/s], the stress measured at
    ``t_after_s`` [s] after the start-up (``tau_pa``: the measured values; default 1 Pa
    placeholders, to be replaced by a model's, e.g. for synthetic data)."""
    ta = np.asarray(t_after_s, float)
    t0 = preshear_s + rest_s
    t = np.concatenate([[preshear_s], [t0] if rest_s > 0 else [], t0 + ta])
    g = np.concatenate([[preshear_1_s], [0.0] if rest_s > 0 else [], np.full(ta.size, rate_1_s)])
    nsched = t.size - ta.size
    tau = np.concatenate([np.full(nsched, np.nan), np.ones(ta.size) if tau_pa is None else tau_pa])
    return ShearTest(str(label), t, g, tau, sigma_ln)


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


def _scene_parts(e):
    """The MPM runs of an experiment (``_SceneExperiment`` parts), or None for one without."""
    if isinstance(e, _SceneExperiment):
        return [e]
    if isinstance(e, RestTimeExperiment):
        return e.runs
    return None


def _runs(parts, values, n_frames):
    """The runs of ``parts`` (MPM experiments of one setup with different ``run_key``: e.g.
    releases after different rests), as one ``vmap`` over their materials: one compiled
    simulation however many rests.  Returns {run_key: (initial state, frames)}."""
    s = parts[0].setup
    if len(parts) == 1:
        return {parts[0].run_key: parts[0].run(values, n_frames)}
    batch = jax.tree.map(lambda *a: jnp.stack(a), *[p.params(values) for p in parts])

    def one(p):
        st = restate(s.state, s.scene, p)
        return st, mpmjax.simulate(s.scene, st, p, n_frames)[1]

    st, fr = jax.vmap(one)(batch)
    return {p.run_key: jax.tree.map(lambda a, i=i: a[i], (st, fr)) for i, p in enumerate(parts)}


def joint_residuals(experiments, values: dict):
    """List of residual vectors, one per experiment.  MPM experiments with the same
    ``run_key`` (same setup, same rest) share one run, carried to the last frame any of them
    needs (e.g. profiles and a runout series of one dam break: one simulation); the different
    runs of one setup (releases after different rests) are one ``vmap`` batch."""
    groups = {}
    for e in experiments:
        for p in _scene_parts(e) or []:
            g = groups.setdefault(id(p.setup), {"parts": {}, "n": 0})
            g["parts"].setdefault(p.run_key, p)
            g["n"] = max(g["n"], p.n_frames_needed)
    runs = {}
    for g in groups.values():
        runs.update(_runs(list(g["parts"].values()), values, g["n"]))
    out = []
    for e in experiments:
        parts = _scene_parts(e)
        out.append(
            e.residuals(values)
            if parts is None
            else jnp.concatenate([p.residuals_from(*runs[p.run_key]) for p in parts])
        )
    return out


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
