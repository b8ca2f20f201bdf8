"""``calibrate``: the whole calibration of ``mpmjax calibrate`` as one Python call.

``calibrate(data, fit=["mu0", "T"], ...)`` loads the measurements, builds the experiments at each
cell size, fits (``fit_multilevel``), estimates the uncertainty (and with ``profile=True`` the
profile likelihood), writes fit.json and the plots to ``out`` (``calibration.report``) and returns
a ``CalibrationResult``.  Its keyword arguments are the command line's options, with the same
defaults; errors (``ValueError``, ``mpmjax.SceneError``, ``calibration.DataError``) name the
options as the command line spells them (``--max-iter`` for ``max_iter``).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

import mpmjax
from mpmjax import STEPS_WARN, check_memory, estimate_run_time_s

from . import report
from .data import load_flow_curve, load_profiles, load_rest_times, load_runout_series, load_shear_tests
from .distributed import check_join_options, is_writer, join, make_local_devices
from .experiments import (
    FlowCurveExperiment,
    ProfileExperiment,
    RestTimeExperiment,
    RunoutSeriesExperiment,
    ShearHistoryExperiment,
    frames_for,
)
from .fit import default_starts
from .multilevel import MultilevelResult, check_levels, experiments_at_cell_size, fit_multilevel
from .params import ParameterSet, check_names
from .profile import check_profile_options, profile_likelihood
from .sweep import FIELD_KEYS
from .uncertainty import REL_STD_WARN

__all__ = [
    "DEFAULT_LEVEL_BUDGET_S",
    "DEFAULT_REFINE",
    "MAX_REFINE",
    "SIGMA_UNITS",
    "CalibrationResult",
    "calibrate",
    "join_options",
]

# experiment kinds of --sigma / --weight, and the unit of each kind's sigma
SIGMA_UNITS = {
    "profiles": "m",
    "runout-series": "m",
    "rest-times": "m",
    "transient": "- (relative, in ln tau)",
    "flow-curve": "- (relative, in ln tau)",
}

# --refine: at most this many halvings (each costs ~8x the previous level's run in 2D)
MAX_REFINE = 3
# the default fit has two levels (h, then h/2): the shift between them is the numerical std, the
# resolution bias that the statistical std does not see (issue 32: one level was confidently wrong,
# mu0 -13 % +- 1 %).  ``levels=1`` (--levels 1) or ``refine=0`` asks for the fast one-level fit.
DEFAULT_REFINE = 1
# a finer level estimated (from the level before it) to take longer than this is announced with
# its estimated cost before it starts, and the warning is kept in fit.json [s]
DEFAULT_LEVEL_BUDGET_S = 600.0


@dataclasses.dataclass
class CalibrationResult:
    """What ``calibrate`` found: the fitted values with their uncertainties, the loss and timings at
    a glance, ``document`` (the fit.json document, every field), and the objects behind them."""

    params: dict[str, float]  # fitted values at the finest level [SI]
    std: dict[str, float]  # total standard deviation: statistical and numerical combined
    std_statistical: dict[str, float]
    std_numerical: dict[str, float]
    loss_initial: float
    loss_final: float
    wall_s: float  # the fit's wall time, all levels (without the profile likelihood)
    compile_s: float
    cpu_s: float
    warnings: list[str]
    document: dict[str, Any]  # fit.json
    multilevel: MultilevelResult
    parameters: ParameterSet
    experiments: list  # the finest level's experiments
    profiles: list  # the measured profiles
    profile_likelihood: dict | None  # name -> ParameterProfile, with profile=True
    levels: list[float]  # the cell sizes fitted at [m], coarse to fine

    @classmethod
    def _of(cls, ml, pset, wall, warnings, doc, profiles, profiles_lr, levels):
        res, comb = ml.result, ml.combined
        return cls(
            params=res.params, std=comb["std"], std_statistical=comb["std_statistical"],
            std_numerical=comb["std_numerical"], loss_initial=ml.levels[0].result.loss_initial,
            loss_final=res.loss_final, wall_s=wall, compile_s=res.compile_s, cpu_s=res.cpu_s, warnings=warnings,
            document=doc, multilevel=ml, parameters=pset, experiments=ml.experiments, profiles=profiles,
            profile_likelihood=profiles_lr, levels=levels,
        )


def join_options(coordinator=None, num_processes=None, process_id=None, distributed=False, devices=None):
    """The validated ``jax.distributed`` options (None for a single-process run); with ``devices``
    host devices are asked for (``make_local_devices``), so this must run before any JAX computation."""
    options = check_join_options(coordinator, num_processes, process_id, distributed)
    make_local_devices(devices)
    return options


def _check_per_kind(values: dict, option: str) -> dict:
    """--sigma / --weight {kind: value}: known kinds, values > 0 and finite; ValueError naming the option."""
    for k, v in values.items():
        if k not in SIGMA_UNITS:
            raise ValueError(f"{option} {k}={v:g}: unknown experiment kind {k!r}; allowed: {', '.join(SIGMA_UNITS)}")
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{option} {k}={v!r}; allowed range: > 0 and finite [{SIGMA_UNITS[k].split()[0]}]")
    return dict(values)


def _level_count(levels):
    """``levels`` as a number of levels (an int, or text that is a plain integer such as "1"),
    else None (cell sizes)."""
    if isinstance(levels, bool):
        return None
    if isinstance(levels, int):
        return levels
    if isinstance(levels, str) and levels.strip().lstrip("+-").isdigit():
        return int(levels.strip())
    return None


def _levels(levels, refine: int | None, h0: float) -> list:
    """Cell sizes of the fit's levels [m], coarse to fine, from --levels / --refine: ``levels`` a
    number of levels (``1``: the one-level fit; ``N``: h, h/2, ..., h/2^(N-1)), cell sizes (a
    sequence, or text "H1,H2,..."), or None; ``refine`` a number of halvings; neither: two levels
    (``DEFAULT_REFINE``)."""
    if levels is not None and refine is not None:
        raise ValueError("--levels and --refine both given; give one")
    count = _level_count(levels)
    if count is not None:
        if not 1 <= count <= MAX_REFINE + 1:
            raise ValueError(
                f"--levels = {count}; allowed range: 1 .. {MAX_REFINE + 1} levels (a plain integer), or cell sizes "
                "[m], e.g. 0.02,0.01"
            )
        refine = count - 1
    elif levels is not None:
        if isinstance(levels, str):
            try:
                return check_levels([v for v in levels.split(",") if v.strip()], "--levels")
            except ValueError as e:
                raise ValueError(f"{e} (got {levels!r})") from None
        return check_levels(levels, "--levels")
    refine = DEFAULT_REFINE if refine is None else refine
    if not 0 <= refine <= MAX_REFINE:
        raise ValueError(f"--refine = {refine}; allowed range: 0 .. {MAX_REFINE} (halvings of the cell size)")
    return [h0 / 2**i for i in range(refine + 1)]


def _scene_overrides(scene, overrides, times_s, init):
    """(scene config, overrides) for ``scene`` with the ``KEY=VALUE`` list ``overrides``: frames
    aligned to the data times ``times_s`` [s] (unless the user set time.t_end_s or time.n_frames)
    and the scene's material keys set to ``init`` (so range errors name the scene key)."""
    overrides = list(overrides or [])
    keys = {o.split("=", 1)[0].strip() for o in overrides}
    cfg0 = mpmjax.load_scene(scene, overrides)
    if not ({"time.t_end_s", "time.n_frames"} & keys):
        t_end, nf = frames_for(list(times_s), cfg0["time.t_end_s"], cfg0["time.n_frames"])
        overrides += [f"time.t_end_s={float(t_end)!r}", f"time.n_frames={int(nf)}"]  # plain numbers, not np.float64
    for k, v in init.items():
        if k in FIELD_KEYS:
            ov = f"{FIELD_KEYS[k]}={float(v)!r}"
            try:  # validated as a scene value, one at a time: the message names the --init item and the key
                mpmjax.load_scene(scene, overrides + [ov])
            except mpmjax.SceneError as e:
                raise ValueError(f"--init {k}={v!r}: {e}") from None
            overrides.append(ov)
    return cfg0, overrides


@dataclasses.dataclass
class _Experiments:
    """``setup -> experiments``: the measurements in hand as experiments of one built scene."""

    profiles: list
    data: str
    bandwidth_m: float
    runout_m: float | None
    runout_sigma_m: float
    sigmas: dict
    weights: dict
    series: Any
    runout_series: str | None
    rests: list | None
    rest_times: str | None
    lambda_rest: float | None
    shear: Any
    transient: str | None
    flow: tuple | None
    flow_curve: str | None

    def weight(self, kind, from_file=None):
        return self.weights.get(kind, from_file if from_file is not None else 1.0)

    def __call__(self, st):
        exps = [
            ProfileExperiment(
                st,
                self.profiles,
                bandwidth_m=self.bandwidth_m,
                sigma_m=self.sigmas.get("profiles"),
                runout_m=self.runout_m,
                runout_sigma_m=self.runout_sigma_m,
                weight=self.weight("profiles"),
                name=Path(self.data).name,
            )
        ]
        if self.series is not None:
            exps.append(self._series(st))
        if self.rests is not None:
            exps.append(self._rests(st))
        if self.shear is not None:
            exps.append(
                ShearHistoryExperiment(
                    st.params.material,
                    self.shear[0],
                    sigma_ln=self.sigmas.get("transient"),
                    weight=self.weight("transient", self.shear[1]),
                    name=Path(self.transient).name,
                )
            )
        if self.flow is not None:
            exps.append(
                FlowCurveExperiment(
                    st.params.material,
                    *self.flow,
                    sigma_ln=self.sigmas.get("flow-curve"),
                    weight=self.weight("flow-curve"),
                    name=Path(self.flow_curve).name,
                )
            )
        return exps

    def _series(self, st):
        series = self.series
        sigma_m = series.sigma_m
        if sigma_m is None:
            sigma_m = self.sigmas.get("runout-series", self.runout_sigma_m)
        return RunoutSeriesExperiment(
            st,
            series.t_s,
            series.x_front_m,
            sigma_m=sigma_m,
            sigma_known=series.sigma_m is not None or "runout-series" in self.sigmas,
            bandwidth_m=self.bandwidth_m,
            weight=self.weight("runout-series", series.weight),
            name=Path(self.runout_series).name,
        )

    def _rests(self, st):
        rests = self.rests
        lam = {r.lambda_rest for r in rests} - {None}
        if len(lam) > 1 or (lam and self.lambda_rest is not None):
            raise ValueError(
                f"{self.rest_times}: lambda_rest differs between rest times ({sorted(lam)}) or is given both in the "
                "file and by --lambda-rest; allowed: one value"
            )
        return RestTimeExperiment(
            st,
            [(r.rest_time_s, r.t_s, r.x_front_m, r.sigma_m) for r in rests],
            sigma_m=self.sigmas.get("rest-times", self.runout_sigma_m),
            sigma_known=all(r.sigma_m is not None for r in rests) or "rest-times" in self.sigmas,
            bandwidth_m=self.bandwidth_m,
            lambda_rest=next(iter(lam), self.lambda_rest),
            weight=self.weight("rest-times", rests[0].weight),
            name=Path(self.rest_times).name,
        )


@dataclasses.dataclass
class _Progress:
    """The fit's progress: a line per level and per iteration on stderr (unless quiet) and
    fit_progress.json in ``out``, by the writing process only."""

    out: Path
    log: Any
    writer: bool
    quiet: bool
    scene_name: str
    levels: list
    n_profiles: int
    data: str
    free: list
    method: str
    starts: int

    def on_level(self, i, h, exps):
        sc = exps[0].setup.scene
        self.log(
            f"calibrate: level {i + 1}/{len(self.levels)}: scene {self.scene_name} at h = {h:g} m "
            f"({sc.n_particles} particles, "
            f"{sc.n_steps} steps of {sc.dt:.3g} s to t = {sc.t_end:g} s), {self.n_profiles} profile(s) from "
            f"{self.data}, fitting {', '.join(self.free)} with {self.method}"
            + (f", {self.starts} start(s)" if i == 0 else ", from the previous level's result")
        )

    def on_estimate(self, i, h, est, budget_s):
        """Before a finer level: its estimated cost, and a warning (kept in ``est``) when it
        exceeds ``budget_s``."""
        est["budget_s"] = budget_s
        est["over_budget"] = est["wall_s"] > budget_s
        how = (
            f"{est['per_evaluation_s']:.3g} s per evaluation at the level before x {est['cost_ratio']:.3g} "
            f"(particles x steps) x up to {est['evaluations']} evaluations + {est['fixed_s']:.3g} s compilation and "
            "optimiser at the level before"
        )
        if est["over_budget"]:
            est["message"] = (
                f"level {i + 1}/{len(self.levels)} (h = {h:g} m) is estimated to take {est['wall_s']:.0f} s, over the "
                f"budget of {budget_s:g} s ({how}); it runs anyway: interrupt and rerun with --levels 1 for the "
                "one-level fit (no resolution bias estimate), fewer --refine-max-iter, or a larger --level-budget-s"
            )
            self.log(f"calibrate: warning: {est['message']}")
        else:
            self.log(f"calibrate: level {i + 1}/{len(self.levels)} (h = {h:g} m): estimated {est['wall_s']:.0f} s "
                     f"({how})")

    def progress(self, level, h, it, max_iter, losses, best, running):
        if not self.writer:
            return
        if not self.quiet:
            vals = ", ".join(f"{k}={v:.4g}" for k, v in best.items())
            lv = f" level {level + 1}/{len(self.levels)}" if len(self.levels) > 1 else ""
            print(f"calibrate:{lv} iteration {it}/{max_iter} loss {float(np.min(losses)):.4e} {vals}", file=sys.stderr)
        mpmjax.atomic_write_text(
            self.out / "fit_progress.json",
            json.dumps(
                {"level": level, "cell_size_m": h, "iteration": it, "loss": float(np.min(losses)), "params": best,
                 "complete": False},
                indent=1,
            ),
        )


def _warnings(ml) -> list:
    """The uncertainty's warnings, the parameters poorly identified once the numerical std is
    added, and the missing numerical std of a one-level fit."""
    unc, comb = ml.uncertainty, ml.combined
    warnings = list(unc.warnings)
    for k in comb["poorly_identified"]:
        if k not in unc.poorly_identified:
            warnings.append(
                f"{k} is poorly identified: its total relative standard deviation {comb['rel_std'][k]:.3g} exceeds "
                f"{REL_STD_WARN:g} (numerical {comb['std_numerical'][k]:.3g}, "
                f"statistical {comb['std_statistical'][k]:.3g})"
            )
    if ml.numerical is None:
        warnings.append(
            "numerical (discretisation) uncertainty not estimated: one level (--levels 1); the std is statistical "
            "only and misses the grid's resolution bias, which can be many times larger (rerun without --levels 1: "
            "the default fits two levels)"
        )
    if ml.optima is not None:
        warnings += ml.optima["warnings"]
    num = ml.numerical
    if num is not None and num.refit_std is not None:
        for k in num.values:
            lin, refit, stat = num.std[k], num.refit_std[k], comb["std_statistical"][k] or 0.0
            if num.method[k] == "linear" and refit > 3 * lin and refit > 2 * stat:
                warnings.append(
                    f"{k}: the refit moved it by {refit:.3g} between the last two levels, "
                    f"{refit / max(lin, 1e-300):.3g}x the shift at fixed parameters ({lin:.3g}): the finer level's "
                    "fit went along a flat valley or to another optimum (the optimiser's path, not only the grid); "
                    "the value is the refit's, its numerical std the fixed-parameter one (std_numerical_refit keeps "
                    "the other)"
                )
            elif num.method[k] == "linear" and lin > 3 * refit and lin > 2 * stat:
                warnings.append(
                    f"{k}: its shift at fixed parameters ({lin:.3g}) is {lin / max(refit, 1e-300):.3g}x the refit's "
                    f"({refit:.3g}): the finer model is not linear over that step (the coarser optimum lies far from "
                    "the finer one), so the numerical std is conservative; std_numerical_refit keeps the other"
                )
    for lv in ml.levels:
        if lv.estimate is not None and lv.estimate.get("over_budget"):
            warnings.append(lv.estimate["message"])
    warnings += _not_converged(ml)
    return warnings


def _not_converged(ml) -> list:
    """A warning where the finest level stopped at its iteration cap: its values and std are then not an
    optimum's (measured: docs/calibration-coverage.md, a finer level capped at 8 iterations in a flat valley)."""
    if not ml.levels or ml.levels[-1].result.converged:
        return []
    r = ml.levels[-1].result
    hist = [float(v) for v in np.min(np.asarray(r.history), axis=1)]
    k = min(3, len(hist) - 1)
    fall = f"; the loss fell from {hist[-1 - k]:.4g} to {hist[-1]:.4g} over the last {k} iteration{'' if k == 1 else 's'}" if k > 0 else ""
    option = "--refine-max-iter" if len(ml.levels) > 1 else "--max-iter"
    return [
        f"the fit stopped at its iteration cap ({r.iterations} iteration{'' if r.iterations == 1 else 's'} at h = {ml.levels[-1].cell_size_m:g} m) before "
        f"its stopping test held{fall}: the values and their std are not an optimum's; raise {option}"
    ]


def _load_data(data, sigmas, weights, sigma_m, runout_series, rest_times, transient, lambda_rest):
    """The measurements and the per-kind noise levels and weights, checked."""
    profiles = load_profiles(data)
    sigmas = _check_per_kind(dict(sigmas or {}), "--sigma")
    weights = _check_per_kind(dict(weights or {}), "--weight")
    if sigma_m is not None:
        if "profiles" in sigmas:
            raise ValueError("--sigma-m and --sigma profiles=... both given; give one")
        sigmas["profiles"] = sigma_m
    series = load_runout_series(runout_series) if runout_series else None
    rests = load_rest_times(rest_times) if rest_times else None
    shear = load_shear_tests(transient) if transient else None
    if lambda_rest is not None and not (np.isfinite(lambda_rest) and lambda_rest >= 0):
        raise ValueError(f"--lambda-rest = {lambda_rest!r}; allowed range: >= 0 and finite [-]")
    return profiles, sigmas, weights, series, rests, shear


def _fit_names(fit, method, gradient) -> list:
    """The names to fit (a list, or the command line's comma-separated text), and the method's gradient."""
    names = [s.strip() for s in fit.split(",") if s.strip()] if isinstance(fit, str) else list(fit)
    if not names:
        raise ValueError("--fit: name at least one parameter, e.g. --fit mu0,n")
    if method == "lm" and gradient == "reverse":  # refused before any scene is built
        raise ValueError(
            "--gradient reverse is invalid with --method lm; allowed: forward or auto (the Jacobian of the "
            "residuals is computed in forward mode, one tangent per parameter), or --method lbfgs / adam"
        )
    return names


def _scene_levels(scene, overrides, data_times, init, levels, refine, profile, profile_options, refine_max_iter):
    """(the coarsest level's scene config, the overrides every level shares, the cell sizes)."""
    cfg0, overrides = _scene_overrides(scene, overrides, data_times, init)
    check_profile_options(*profile_options, "--profile-")  # also without --profile: a bad value is refused, not ignored
    if refine_max_iter is not None and refine_max_iter < 1:
        raise ValueError(f"--refine-max-iter = {refine_max_iter}; allowed range: integer >= 1")
    levels = _levels(levels, refine, float(cfg0["domain.cell_size_m"]))
    overrides = [o for o in overrides if o.split("=", 1)[0].strip() != "domain.cell_size_m"]
    cfgs = []
    for h in levels:
        try:
            cfgs.append(mpmjax.load_scene(scene, overrides + [f"domain.cell_size_m={h!r}"]))
        except mpmjax.SceneError as e:
            raise ValueError(f"--levels / --refine: cell size {h:g} m: {e}") from None
    check_memory(cfgs[-1])  # the finest level, before anything is built: one that cannot fit is refused (exit 2)
    return cfgs[0], overrides, levels


def _check_reach(setup, runout_m, latest, time_set: bool) -> None:
    """``ValueError`` for a ``--runout-m`` beyond the domain, and for data times that need more than
    ``STEPS_WARN`` steps per model evaluation (``latest``: (time [s], file) of the latest data time;
    unless the user set the run's length with --set)."""
    sc, info = setup.scene, setup.info
    axis = info["runout_axis"]
    reach = float(sc.hi[axis]) - float(info["runout_origin_m"])
    if runout_m is not None and runout_m > reach:
        raise ValueError(
            f"--runout-m = {runout_m!r} is invalid: allowed range: 0 .. {reach:g} m (from the runout origin "
            f"{float(info['runout_origin_m']):g} m to the domain's end along axis {axis})"
        )
    if not time_set and latest is not None and sc.n_steps > STEPS_WARN:
        t, src = latest
        raise ValueError(
            f"{src}: t_s = {t:g} s needs {sc.n_steps:.3g} steps of {sc.dt:.3g} s for every model evaluation (about "
            f"{estimate_run_time_s(sc.n_particles, sc.n_steps, sc.dim):.3g} s each on a CPU); allowed: data times the "
            f"run reaches in at most {STEPS_WARN:.0e} steps (t_s <= {STEPS_WARN * sc.dt:.3g} s), or set "
            "time.t_end_s with --set to fit it anyway"
        )


def calibrate(
    data: str | Path,
    *,
    fit: Sequence[str] | str,
    scene: str | Path = "dambreak-lab",
    init: dict[str, float] | None = None,
    bounds: dict[str, tuple[float, float]] | None = None,
    transforms: dict[str, str] | None = None,
    overrides: Sequence[str] | None = None,
    method: str = "lm",
    max_iter: int = 50,
    learning_rate: float = 0.05,
    rtol: float = 1e-4,
    patience: int = 5,
    starts: int | None = None,
    seed: int = 0,
    gradient: str = "auto",
    sigma_m: float | None = None,
    bandwidth_m: float | None = None,
    runout_m: float | None = None,
    runout_sigma_m: float | None = None,
    flow_curve: str | Path | None = None,
    runout_series: str | Path | None = None,
    rest_times: str | Path | None = None,
    lambda_rest: float | None = None,
    transient: str | Path | None = None,
    sigmas: dict[str, float] | None = None,
    weights: dict[str, float] | None = None,
    refine: int | None = None,
    levels: Sequence[float] | int | str | None = None,
    refine_max_iter: int | None = None,
    level_budget_s: float | None = None,
    profile: bool = False,
    profile_points: int = 9,
    profile_width: float = 4.0,
    profile_max_iter: int = 10,
    out: str | Path = "calibration-out",
    quiet: bool = False,
    coordinator: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
    distributed: bool = False,
) -> CalibrationResult:
    """Fit the parameters ``fit`` of ``scene`` to the profiles in ``data`` (and the other
    measurements given); writes fit.json and the plots to ``out`` and returns the result.

    The arguments are ``mpmjax calibrate``'s options (docs/calibration.md): ``overrides`` is
    ``--set`` (``KEY=VALUE`` strings), ``sigmas`` / ``weights`` are ``--sigma`` / ``--weight`` by
    experiment kind (``SIGMA_UNITS``), ``init`` / ``bounds`` / ``transforms`` are by parameter name.

    Levels: by default two (the scene's cell size h, then h/2; ``DEFAULT_REFINE``), so that the
    numerical std measures the resolution bias; ``levels=1`` is the one-level fit (its outputs say
    that the bias is not estimated), ``levels=N`` N levels, ``levels=[h1, h2, ...]`` (or the text
    "h1,h2") the cell sizes, ``refine=K`` K halvings.  ``level_budget_s`` (default
    ``DEFAULT_LEVEL_BUDGET_S``): a finer level estimated to take longer is announced, with its
    estimated cost, before it starts (and the warning is kept in fit.json); the fit goes on.

    Starts: ``starts=None`` (the default) runs ``calibration.fit.default_starts``: 4 starts for
    three or more free parameters, else 1; fit.json's ``optima`` lists every distinct optimum
    and its loss, with a warning where two within the noise level disagree."""
    out = Path(out)
    overrides_given = list(overrides or [])
    join(join_options(coordinator, num_processes, process_id, distributed))  # before any JAX computation
    writer = is_writer()  # only process 0 writes --out and prints progress
    log = (lambda *a: None) if quiet or not writer else (lambda *a: print(*a, file=sys.stderr))
    profiles, sigmas, weights, series, rests, shear = _load_data(
        data, sigmas, weights, sigma_m, runout_series, rest_times, transient, lambda_rest
    )
    data_times = [p.t_s for p in profiles] + (list(series.t_s) if series else [])
    data_times += [float(t) for r in rests or [] for t in r.t_s]
    sources = [(p.t_s, str(data)) for p in profiles if p.t_s is not None]
    sources += [(float(t), str(runout_series)) for t in (series.t_s if series else [])]
    sources += [(float(t), str(rest_times)) for r in rests or [] for t in r.t_s]
    latest = max(sources, default=None)
    names = _fit_names(fit, method, gradient)
    budget = DEFAULT_LEVEL_BUDGET_S if level_budget_s is None else float(level_budget_s)
    if not (budget > 0 and np.isfinite(budget)):
        raise ValueError(f"--level-budget-s = {level_budget_s!r}; allowed range: > 0 and finite [s]")
    init = dict(init or {})
    cfg, overrides, levels = _scene_levels(
        scene, overrides, data_times, init, levels, refine, profile,
        (profile_points, profile_width, profile_max_iter), refine_max_iter,
    )
    named = mpmjax.make_params(cfg)  # the names the scene carries, before it is built
    check_names(names, named, "--fit", cfg)
    check_names(init, named, "--init", cfg)
    setup = mpmjax.build(cfg)
    time_set = any(o.split("=", 1)[0].strip() in ("time.t_end_s", "time.n_frames") for o in overrides_given or [])
    _check_reach(setup, runout_m, latest, time_set)
    bounds = dict(bounds or {})
    if cfg["model.internal_friction_deg"] is not None and "friction" in names and "friction" not in bounds:
        # a granular column's bed friction stays at or below tan(phi) (mpmjax.fit_parameters with the scene)
        bounds["friction"] = mpmjax.fit_parameters(setup.params, cfg)["friction"].bounds
    pset = ParameterSet.from_names(names, setup.params, init=init, bounds=bounds, transforms=dict(transforms or {}))
    starts = default_starts(len(pset.free)) if starts is None else starts
    # the observable is the same at every level: bandwidth and runout sigma fixed in metres
    bandwidth_m = bandwidth_m if bandwidth_m is not None else levels[0]
    runout_sigma_m = runout_sigma_m if runout_sigma_m is not None else 2 * levels[0]
    flow = load_flow_curve(flow_curve) if flow_curve else None
    make = _Experiments(
        profiles, data, bandwidth_m, runout_m, runout_sigma_m, sigmas, weights, series, runout_series, rests,
        rest_times, lambda_rest, shear, transient, flow, flow_curve,
    )
    build_at = experiments_at_cell_size(scene, overrides, make)

    def make_experiments(h):
        return make(setup) if h == levels[0] else build_at(h)

    if writer:
        out.mkdir(parents=True, exist_ok=True)
    shown = _Progress(out, log, writer, quiet, cfg["name"], levels, len(profiles), data, pset.free, method, starts)
    t0 = time.perf_counter()
    ml = fit_multilevel(
        make_experiments, pset, levels, max_iter=max_iter, refine_max_iter=refine_max_iter, n_starts=starts,
        progress=shown.progress, on_level=shown.on_level, on_estimate=lambda i, h, est: shown.on_estimate(
            i, h, est, budget), method=method, learning_rate=learning_rate, rtol=rtol, patience=patience, seed=seed,
        gradient=gradient,
    )
    wall = time.perf_counter() - t0
    warnings = _warnings(ml)
    profiles_lr = None
    if profile:
        log(f"calibrate: profile likelihood of {', '.join(pset.free)} ({profile_points} points each)")
        profiles_lr = profile_likelihood(
            ml.experiments, pset, ml.result.params, ml.uncertainty, n_points=profile_points,
            width_sigma=profile_width, max_iter=profile_max_iter,
        )
        warnings += [p.warning for p in profiles_lr.values() if p.warning]
    for w in warnings:
        log(f"calibrate: warning: {w}")
    doc = report.fit_document(
        ml, pset, warnings, wall, method, cfg["name"], overrides, levels, bandwidth_m, data, profiles, profiles_lr
    )
    result = CalibrationResult._of(ml, pset, wall, warnings, doc, profiles, profiles_lr, levels)
    if writer:
        report.write_outputs(result, out, log)
    return result
