"""``run_design``: the whole of ``mpmjax design`` as one Python call: rank candidate measurements
by the information they add (``calibration.design``), write design.json and design.png.

Candidates are tables with the keys of :data:`CANDIDATE_KEYS` (checked by ``check_candidate``),
from a TOML file of ``[[candidate]]`` tables (``load_candidates``; docs/calibration.md,
"Experiment design") and/or built by the caller (the command line builds them from its flags,
``--profile-times``, ``--shear-rates``, ...).  Invalid input raises ``ValueError`` or
``DataError`` naming the option or entry, the key, the value and the allowed range.
"""

from __future__ import annotations

import json
import math
import sys
import tomllib
from pathlib import Path

import numpy as np

import mpmjax

from .data import DataError, load_flow_curve, load_profiles
from .design import (
    ProfileRequest,
    design,
    flow_curve_candidate,
    plot_design,
    profile_candidates,
    rheometer_candidate,
    table_lines,
)
from .experiments import FlowCurveExperiment, ProfileExperiment
from .params import UNITS, ParameterSet
from .run import _scene_overrides

REQUIRED = object()
# kind -> key -> (type, unit, default, meaning); default REQUIRED: must be given; None: see meaning
CANDIDATE_KEYS = {
    "profile": {
        "times_s": ("list", "s", REQUIRED, "profile times; one candidate per time and spacing"),
        "spacing_m": ("list", "m", None, "station spacing(s) (default: 2 cells)"),
        "sigma_m": ("float", "m", None, "height noise (default: the data's, as for calibrate)"),
        "x_range_m": ("pair", "m", None, "stations from lo to hi (default: the domain)"),
    },
    "runout": {"sigma_m": ("float", "m", REQUIRED, "noise of the final runout (at the scene's last time)")},
    "transient": {
        "rates_1_s": ("list", "1/s", REQUIRED, "shear rates, one constant-shear test each (one candidate)"),
        "rest_s": ("list", "s", [0.0], "rest before shearing; one candidate per rest time (0: from lambda0)"),
        "t_end_s": ("float", "s", 60.0, "length of each test"),
        "n_times": ("int", "-", 30, "samples, log-spaced from t_end_s/1000 to t_end_s"),
        "sigma_ln": ("float", "-", 0.05, "relative noise of the viscosity (std of ln mu)"),
    },
    "flow_curve": {
        "rates_1_s": ("list", "1/s", REQUIRED, "steady flow-curve rates"),
        "sigma_ln": ("float", "-", 0.05, "relative noise of the stress (std of ln tau)"),
    },
    "dambreak_after_rest": {
        "rest_s": ("list", "s", REQUIRED, "rest before the release; one simulation per rest time"),
        "times_s": ("list", "s", REQUIRED, "profile times"),
        "spacing_m": ("list", "m", None, "station spacing(s) (default: 2 cells)"),
        "sigma_m": ("float", "m", None, "height noise (default: the data's)"),
        "x_range_m": ("pair", "m", None, "stations from lo to hi (default: the domain)"),
    },
}


def _number(where, key, v, unit):
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ValueError(f"{where}: {key} = {v!r}; allowed: a finite number [{unit}]")
    return float(v)


def check_candidate(where, kind, entry):
    """Validate one candidate table (``where`` names it in messages); returns it with defaults."""
    if kind not in CANDIDATE_KEYS:
        raise ValueError(f"{where}: kind = {kind!r}; allowed: {', '.join(CANDIDATE_KEYS)}")
    keys = CANDIDATE_KEYS[kind]
    extra = sorted(set(entry) - set(keys) - {"kind"})
    if extra:
        raise ValueError(f"{where}: unknown key(s) {extra} for kind {kind!r}; allowed: {', '.join(keys)}")
    out = {"kind": kind}
    for k, (typ, unit, default, _) in keys.items():
        if k not in entry:
            if default is REQUIRED:
                raise ValueError(f"{where}: kind {kind!r} needs {k} [{unit}]")
            out[k] = default
            continue
        v = entry[k]
        if typ == "list":
            vs = v if isinstance(v, list) else [v]
            if not vs:
                raise ValueError(f"{where}: {k} is empty; give at least one value [{unit}]")
            vs = [_number(where, k, x, unit) for x in vs]
            lo_ok = (lambda x: x >= 0) if k in ("rest_s",) else (lambda x: x > 0)
            bad = [x for x in vs if not lo_ok(x)]
            if bad:
                rng = ">= 0" if k == "rest_s" else "> 0"
                raise ValueError(f"{where}: {k} = {bad[0]!r}; allowed range: {rng} [{unit}]")
            out[k] = vs
        elif typ == "pair":
            if not (isinstance(v, list) and len(v) == 2):
                raise ValueError(f"{where}: {k} = {v!r}; allowed: [lo, hi] [{unit}]")
            out[k] = tuple(_number(where, k, x, unit) for x in v)
        elif typ == "int":
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{where}: {k} = {v!r}; allowed range: integer >= 1")
            out[k] = v
        else:
            x = _number(where, k, v, unit)
            if not x > 0:
                raise ValueError(f"{where}: {k} = {x!r}; allowed range: > 0 [{unit}]")
            out[k] = x
    return out


def load_candidates(path) -> tuple[list, dict]:
    """([checked candidate tables], top-level settings) from a TOML file (``[[candidate]]`` tables,
    optional ``prior_factor``)."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such file")
    try:
        doc = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise DataError(f"{path}: not valid TOML: {e}") from None
    extra = sorted(set(doc) - {"candidate", "prior_factor"})
    if extra:
        raise ValueError(f"{path}: unknown key(s) {extra}; allowed: [[candidate]] tables and prior_factor")
    tables = doc.get("candidate", [])
    if not isinstance(tables, list) or not tables:
        raise ValueError(f"{path}: no [[candidate]] table")
    out = []
    for i, t in enumerate(tables, 1):
        where = f"{path}: candidate {i}"
        if "kind" not in t:
            raise ValueError(f"{where}: no kind; allowed: {', '.join(CANDIDATE_KEYS)}")
        out.append(check_candidate(where, t["kind"], t))
    settings = {}
    if "prior_factor" in doc:
        settings["prior_factor"] = _number(str(path), "prior_factor", doc["prior_factor"], "-")
    return out, settings


def load_estimate(estimate=None, fit=None, init=None) -> tuple[list, dict]:
    """(fitted names, estimate by name) from a fit.json of ``mpmjax calibrate`` (``estimate``), the
    names ``fit`` (default: the fit.json's fitted ones) and values ``init`` that override it."""
    values = {}
    fitted = []
    if estimate:
        path = Path(estimate)
        try:
            doc = json.loads(path.read_text())
            fitted = list(doc["params"])
            values.update({k: float(v) for k, v in doc["params"].items()})
            values.update({k: float(v) for k, v in doc.get("fixed", {}).items()})
        except FileNotFoundError:
            raise DataError(f"--estimate {path}: no such file") from None
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
            raise DataError(f"--estimate {path}: not a fit.json of mpmjax calibrate ({e})") from None
    values.update(init or {})
    names = list(fit) if fit is not None else fitted
    if not names:
        raise ValueError("--fit: name the parameters (e.g. --fit mu0,alpha,T,n,lambda0) or give --estimate FIT_JSON")
    return names, values


def run_design(
    data,
    *,
    scene="dambreak-lab",
    fit=None,
    estimate=None,
    init=None,
    overrides=None,
    sigma_m=None,
    bandwidth_m=None,
    flow_curve=None,
    candidates=None,
    entries=(),
    prior_factor=None,
    out="design-out",
    quiet=False,
) -> dict:
    """Rank the candidate measurements of the TOML file ``candidates`` and the checked tables
    ``entries`` (``check_candidate``) by the information they add to the profiles in ``data`` (and the
    flow curve ``flow_curve``) at the estimate (``load_estimate(estimate, fit, init)``) on ``scene``
    with the ``overrides`` (``KEY=VALUE``); writes ``out``/design.json and design.png, prints the
    table and returns design.json's document.  The arguments are ``mpmjax design``'s options."""
    out = Path(out)
    log = (lambda *a: None) if quiet else (lambda *a: print(*a, file=sys.stderr))
    profiles = load_profiles(data)
    names, init = load_estimate(estimate, fit, init)
    file_entries, settings = load_candidates(candidates) if candidates else ([], {})
    entries = file_entries + list(entries)
    if not entries:
        raise ValueError("no candidate measurement: give --candidates TOML or --profile-times / --shear-rates / ...")
    prior = prior_factor if prior_factor is not None else settings.get("prior_factor", 10.0)
    times = [p.t_s for p in profiles] + [t for e in entries for t in e.get("times_s") or []]
    cfg0, overrides = _scene_overrides(scene, overrides, times, init)
    setup = mpmjax.build(mpmjax.load_scene(scene, overrides))
    h = setup.scene.h
    pset = ParameterSet.from_names(names, setup.params, init=init)
    theta = {k: pset.specs[k].init for k in pset.free}
    bw = bandwidth_m
    current = [ProfileExperiment(setup, profiles, bandwidth_m=bw, sigma_m=sigma_m, name=Path(data).name)]
    if flow_curve:
        current.append(FlowCurveExperiment(setup.params.material, *load_flow_curve(flow_curve),
                                           name=Path(flow_curve).name))
    # candidate profile noise: as calibrate's default for the data in hand
    data_sigma = [float(np.median(p.sigma_m)) for p in profiles if p.sigma_m is not None]
    sigma0 = float(np.median(data_sigma)) if data_sigma else (
        sigma_m if sigma_m is not None else 0.05 * max(float(np.max(p.h_m)) for p in profiles))
    mat = setup.params.material
    plain, runout, cands = [], None, []
    for e in entries:
        k = e["kind"]
        if k in ("profile", "dambreak_after_rest"):
            reqs = [ProfileRequest(t, sp, e["sigma_m"] or sigma0, e["x_range_m"])
                    for t in e["times_s"] for sp in (e["spacing_m"] or [2 * h])]
            if k == "profile":
                plain += reqs
            else:
                for r in e["rest_s"]:
                    cands += profile_candidates(setup, reqs, bandwidth_m=bw, rest_s=r)
        elif k == "runout":
            runout = e["sigma_m"]
        elif k == "transient":
            for r in e["rest_s"]:
                cands.append(rheometer_candidate(mat, e["rates_1_s"], t_end_s=e["t_end_s"], n_times=e["n_times"],
                                                 sigma_ln=e["sigma_ln"], rest_s=r))
        else:
            cands.append(flow_curve_candidate(mat, e["rates_1_s"], sigma_ln=e["sigma_ln"]))
    if plain or runout is not None:
        cands = profile_candidates(setup, plain, bandwidth_m=bw, runout_sigma_m=runout) + cands
    log(f"design: {len(cands)} candidate(s), parameters {', '.join(pset.free)} at "
        + ", ".join(f"{k} = {v:.4g}" for k, v in theta.items()) + f"; scene {cfg0['name']} at h = {h:g} m")
    res = design(current, pset, theta, cands, prior_factor=prior)
    doc = {**res.as_dict(units={k: UNITS.get(k, "SI") for k in pset.free}), "scene": cfg0["name"],
           "scene_overrides": overrides, "data": str(data), "code_version": mpmjax.__version__}
    out.mkdir(parents=True, exist_ok=True)
    mpmjax.atomic_write_text(out / "design.json", json.dumps(doc, indent=1))
    plot_design(res, out / "design.png")
    for line in table_lines(res):
        print(line)
    log(f"wrote {out / 'design.json'}, {out / 'design.png'}")
    return doc
