"""Multi-fidelity fits: the cheap iterations at a coarse cell size, then the same fit continued
at finer ones, starting from the coarser result; the shift between the levels is the fit's
numerical (discretisation) uncertainty.

``fit_multilevel(make_experiments, pset, levels)`` calls ``make_experiments(h)`` for every
cell size h in ``levels`` (coarse to fine, e.g. ``[h, h / 2]``), fits level 0 from ``pset``'s
initial values and every later level from the previous level's result, then at the finest
level computes the Gauss-Newton (statistical) uncertainty and, from the values per level,
the numerical one (``calibration.uncertainty.numerical_uncertainty``: the last shift, or
with three levels a Richardson estimate) and their combination
(``calibration.uncertainty.combine``).  ``experiments_at_cell_size`` builds
``make_experiments`` from a scene and a recipe for its experiments.

The experiments must compare the same observable at every level: keep the kernel bandwidth
and any runout sigma fixed in metres (their defaults are one and two cells).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from typing import Any, NamedTuple

import mpmjax

from .fit import FitResult, fit
from .optima import distinct_optima
from .params import ParameterSet
from .uncertainty import (
    NumericalUncertainty,
    Uncertainty,
    combine,
    fixed_parameter_shift,
    gauss_newton,
    numerical_uncertainty,
)

__all__ = [
    "LevelFit",
    "MultilevelResult",
    "check_levels",
    "estimate_level_cost",
    "experiments_at_cell_size",
    "fit_multilevel",
]


class LevelFit(NamedTuple):
    """One level: cell_size_m [m], n_particles, n_steps (of the first experiment with a
    scene, else None), the :class:`calibration.fit.FitResult` and, for a finer level, the
    cost estimated before it started (:func:`estimate_level_cost`; None for level 0)."""

    cell_size_m: float
    n_particles: int | None
    n_steps: int | None
    result: FitResult
    estimate: dict | None = None


class MultilevelResult(NamedTuple):
    """levels: :class:`LevelFit` per level, coarse to fine; params: the finest level's values;
    experiments / pset: the finest level's (pset starts at the previous level's values);
    uncertainty: Gauss-Newton at the finest level; numerical: the discretisation uncertainty
    (None with one level); combined: ``calibration.uncertainty.combine`` (std_statistical,
    std_numerical, std, rel_std, poorly_identified); optima: the distinct optima of level 0's
    starts (``calibration.optima.distinct_optima``; None with one start)."""

    levels: list
    params: dict
    experiments: list
    pset: Any
    uncertainty: Uncertainty
    numerical: NumericalUncertainty | None
    combined: dict
    optima: dict | None = None

    @property
    def result(self) -> FitResult:
        """The finest level's fit."""
        return self.levels[-1].result


def check_levels(levels, what: str = "levels") -> list:
    """The cell sizes as floats, or ValueError naming ``what``, the value and the allowed range."""
    try:
        hs = [float(h) for h in levels]
    except (TypeError, ValueError):
        raise ValueError(f"{what} = {levels!r}; allowed: cell sizes [m], e.g. 0.02,0.01") from None
    if not hs or any(not (math.isfinite(h) and h > 0) for h in hs) or any(b >= a for a, b in zip(hs, hs[1:])):
        raise ValueError(
            f"{what} = {hs}; allowed: one or more cell sizes > 0 [m], strictly decreasing (coarse to fine)"
        )
    return hs


def experiments_at_cell_size(scene, overrides, make):
    """``h -> make(mpmjax.build(scene at cell size h))``: ``scene`` a built-in name or TOML
    path, ``overrides`` its ``KEY=VALUE`` list (every level shares them; ``domain.cell_size_m``
    is set per level), ``make(setup) -> list of experiments``."""
    base = [o for o in (overrides or []) if o.split("=", 1)[0].strip() != "domain.cell_size_m"]

    def at(h):
        return make(mpmjax.build(mpmjax.load_scene(scene, base + [f"domain.cell_size_m={float(h)!r}"])))

    return at


def _restart(pset: ParameterSet, params: dict) -> ParameterSet:
    """``pset`` with every free parameter's initial value moved to ``params`` (kept strictly
    inside its bounds, where the transform is invertible)."""
    specs = []
    for k, s in pset.specs.items():
        if s.fixed:
            specs.append(s)
            continue
        v = float(params[k])
        if s.transform == "log" and s.lo is not None:
            a, b = math.log(s.lo), math.log(s.hi)
            v = math.exp(min(max(math.log(v), a + 1e-6 * (b - a)), b - 1e-6 * (b - a)))
        elif s.lo is not None and s.hi is not None:
            v = min(max(v, s.lo + 1e-6 * (s.hi - s.lo)), s.hi - 1e-6 * (s.hi - s.lo))
        elif s.lo is not None or s.transform == "softplus":
            lo = 0.0 if s.lo is None else s.lo
            v = max(v, lo + 1e-9 * max(abs(lo), 1.0))
        specs.append(dataclasses.replace(s, init=v))
    return ParameterSet(specs, pset.material)


def _scene_of(exps):
    return next((e.setup.scene for e in exps if hasattr(e, "setup")), None)


def estimate_level_cost(prev: LevelFit, scene_next, max_iter: int) -> dict:
    """The wall time a finer level will take, estimated before it starts from the level before
    it (``prev``): that level's time running the model per evaluation (``FitResult.run_s`` over
    its evaluations) times the cost ratio of one run, (particles x steps) of ``scene_next`` over
    ``prev``'s (about 8 for a halving in 2D: 4x the particles, 2x the steps; 16 in 3D), times at
    most ``max_iter`` + 2 evaluations (one per Levenberg-Marquardt iteration, the start's, and the
    Gauss-Newton uncertainty's), plus the rest of the previous level's wall time again
    (compilation and the optimiser's own work, which do not grow with the grid to first order).
    An upper bound on the iterations; measured against the actual fine level in
    docs/calibration-coverage.md.  Returns {"wall_s", "cost_ratio", "per_evaluation_s",
    "evaluations", "fixed_s"}."""
    r = prev.result
    evals = sum((r.evaluations or {}).values()) or (r.iterations + 1)
    run = r.run_s if math.isfinite(r.run_s) else max(r.wall_s - r.compile_s, 0.0)
    per_eval = run / max(evals, 1)
    fixed = max(r.wall_s - run, 0.0)
    ratio = 1.0
    if scene_next is not None and prev.n_particles and prev.n_steps:
        ratio = (scene_next.n_particles * scene_next.n_steps) / (prev.n_particles * prev.n_steps)
    n_eval = int(max_iter) + 2
    wall = fixed + per_eval * ratio * n_eval
    return {"wall_s": wall, "cost_ratio": ratio, "per_evaluation_s": per_eval, "evaluations": n_eval,
            "fixed_s": fixed}


def _default_progress(stream=sys.stderr):
    def cb(level, h, it, max_iter, losses, best, running):
        vals = ", ".join(f"{k}={v:.4g}" for k, v in best.items())
        loss = float(min(losses))
        stream.write(f"calibrate: level {level} (h = {h:g} m) iteration {it}/{max_iter} loss {loss:.4e} {vals}\n")
        stream.flush()

    return cb


def fit_multilevel(
    make_experiments,
    pset: ParameterSet,
    levels,
    *,
    max_iter: int = 50,
    refine_max_iter: int | None = None,
    n_starts: int = 1,
    progress: Any = True,
    on_level: Any = None,
    on_estimate: Any = None,
    **fit_kwargs,
) -> MultilevelResult:
    """Fit at every cell size of ``levels`` (coarse to fine), each level from the previous
    one's result; see the module docstring.

    make_experiments: ``h -> list of experiments`` at cell size h [m]; pset: the parameters
    and initial values of level 0; max_iter: iterations at level 0; refine_max_iter: at every
    later level (default ``max_iter``); n_starts: multi-start at level 0 only (later levels
    start from its best); progress: True, False or ``cb(level, h, iteration, max_iter, losses,
    best_theta, running)``; on_level: ``cb(level, h, experiments)`` before each level's fit;
    on_estimate: ``cb(level, h, estimate)`` before each finer level's fit, with its estimated
    cost (:func:`estimate_level_cost`);
    fit_kwargs: passed to :func:`calibration.fit.fit` (method, rtol, patience, gradient, ...).
    """
    hs = check_levels(levels)
    refine_max_iter = max_iter if refine_max_iter is None else refine_max_iter
    cb = _default_progress() if progress is True else (progress or None)
    out, ps, exps, optima = [], pset, None, None
    for i, h in enumerate(hs):
        exps = make_experiments(h)
        if on_level is not None:
            on_level(i, h, exps)
        est = None
        if i > 0:
            ps = _restart(pset, out[-1].result.params)
            est = estimate_level_cost(out[-1], _scene_of(exps), refine_max_iter)
            if on_estimate is not None:
                on_estimate(i, h, est)
        prog = (lambda *a, _i=i, _h=h: cb(_i, _h, *a)) if cb is not None else False
        res = fit(
            exps,
            ps,
            max_iter=max_iter if i == 0 else refine_max_iter,
            n_starts=n_starts if i == 0 else 1,
            progress=prog,
            **fit_kwargs,
        )
        if i == 0 and len(res.finals) > 1:
            optima = distinct_optima(res, exps, ps)
        sc = _scene_of(exps)
        out.append(LevelFit(h, None if sc is None else sc.n_particles, None if sc is None else sc.n_steps, res, est))
    unc = gauss_newton(exps, ps, out[-1].result.params)
    num = None
    if len(hs) > 1:
        # the numerical std at fixed parameters: the last level's residual change at the previous
        # optimum carried through the Gauss-Newton normal equations (no re-optimisation)
        linear, _ = fixed_parameter_shift(ps, out[-1].result, exps)
        num = numerical_uncertainty(hs, {k: [lv.result.params[k] for lv in out] for k in ps.free}, linear=linear)
    return MultilevelResult(out, out[-1].result.params, exps, ps, unc, num, combine(unc, num), optima)
