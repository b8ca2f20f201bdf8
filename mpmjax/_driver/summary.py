"""summary.json: one builder for every status (``status_summary``: running, interrupted, failed,
complete), the facts every status carries (``base_summary``), the complete run's metrics
(``complete_summary``, ``_scenario_metrics``) and the two ways it is written (``write_summary``;
``write_summary_anyway``, which falls back to rewriting the file in place)."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np

from .. import _metrics, _shallow, _split
from .._io import _jsonable, atomic_write_text
from .._schema import SCHEMA
from .._version import __version__


def base_summary(cfg: dict, source: str, overrides: list, setup, warnings: list) -> dict:
    """The facts of the run that summary.json has whatever its status."""
    sc, info = setup.scene, setup.info
    return {
        "scene": cfg["name"],
        "scene_source": source,
        "overrides": overrides,
        "dim": sc.dim,
        "n_particles": sc.n_particles,
        "n_steps": sc.n_steps,
        "dt_s": sc.dt,
        "t_end_s": sc.t_end,
        "warnings": warnings,
        # map placement (scene = map - map_origin_m) and the breach release's volumes (docs/output.md)
        **{k: info[k] for k in ("map", "release") if k in info},
    }


def status_summary(base: dict, status: str, complete: bool = False, **fields) -> dict:
    """summary.json of a run in ``status`` ("running", "interrupted", "failed", "complete"): the
    ``base_summary`` facts, the status, the status's own ``fields`` in the order given, and
    ``complete`` last."""
    return dict(base, status=status, **fields, complete=complete)


def write_summary(path: Path, doc: dict) -> None:
    """Write summary.json atomically (an ``OSError`` where that fails)."""
    atomic_write_text(path, json.dumps(doc, indent=2))


def write_summary_anyway(path: Path, doc: dict) -> bool:
    """Write summary.json; if the folder no longer takes new files (the atomic write needs a
    temporary file), rewrite the existing summary.json in place.  Returns whether it worked."""
    text = json.dumps(_jsonable(doc), indent=2)
    try:
        atomic_write_text(path, text)
        return True
    except OSError:
        pass
    try:
        with open(path, "r+") as f:
            f.write(text)
            f.truncate()
        return True
    except OSError:
        return False


def _scenario_metrics(setup, state, times, kinetic) -> dict:
    """summary.json scenario metrics (definitions in docs/output.md and mpmjax._metrics):
    kinetic energy per frame, time to rest (1 % of the peak kinetic energy), mobilised
    fraction (share of the final material displaced by more than one cell size h from where
    it started or was released), the final free-surface profile along the runout axis (bins of
    width h over the domain; null where empty) and its beach slope."""
    sc, info = setup.scene, setup.info
    axis = info["runout_axis"]
    # inflow pool particles are parked where they are released (half a layer behind the exit)
    moved_from = np.asarray(setup.state.x)
    x, act = np.asarray(state.x), np.asarray(state.active)
    edges = np.arange(sc.lo[axis], sc.hi[axis] + 0.5 * sc.h, sc.h)
    xc, top = _metrics.surface_profile(x, act, edges, info["particle_spacing_m"], axis=axis)
    slope = _metrics.beach_slope(xc, top, bed=sc.lo[-1], min_depth_m=info["particle_spacing_m"])

    def fin(a):
        return float(a) if np.isfinite(a) else None

    return {
        "kinetic_energy_J": kinetic,
        "kinetic_energy_unit": "J per metre of depth" if sc.dim == 2 else "J",
        "time_to_rest_s": fin(_metrics.time_to_rest(times, kinetic, rel_threshold=0.01)),
        # weighted by the initial volumes: where columns split (_split) a seeded column's displacement stands for the
        # children it gave its volume to (their slots' start is a parking place; the slots start with volume 0);
        # elsewhere the volumes never change
        "mobilised_fraction": fin(_metrics.mobilised_fraction(moved_from, x, act, sc.h, vol0=np.asarray(setup.state.vol0))),
        "mobilised_distance_m": sc.h,
        "surface_profile_x_m": [float(a) for a in xc],
        "surface_profile_z_m": [fin(a) for a in top],
        "beach_slope": fin(slope),
    }


def complete_summary(base: dict, setup, state, acc: dict, schedule, compile_s: float, gauge) -> tuple[dict, list]:
    """summary.json of a complete run (before the hazard and plan-view parts are added), and the
    warnings the run's end adds (also added to "warnings"): the final deposit's resolution, a front
    still advancing, a depth-averaged tip creeping, the split's spare slots used up.  ``schedule``:
    the particles stepped per frame; ``gauge``: the runout gauge."""
    sc, info = setup.scene, setup.info
    rho = float(setup.params.material.rho)
    wall = acc["wall_s"]
    times, fronts, kinetic = acc["times"], acc["fronts"], acc["kinetic"]
    mass1 = float(np.sum(np.asarray(state.vol0) * np.asarray(state.active))) * rho
    thick = gauge.max_thickness(state.x, state.vol0, state.active)
    shallow = sc.formulation == "depth-averaged"
    # depth-averaged: the grid resolves the deposit in plan, not in depth: its length along the flow in cells
    across = gauge.extent(state.x, state.vol0, state.active) / sc.h if shallow else thick / sc.h
    summary = status_summary(
        base,
        "complete",
        complete=True,
        wall_s=wall,
        compile_s=compile_s,
        # particle-steps actually stepped: a staged pipe pour steps a prefix of the buffer per frame
        particle_steps_per_s=sum(schedule) * sc.steps_per_frame / wall,
        particles_stepped_mean=sum(schedule) / len(schedule),
        mass_initial_kg=acc["mass0"],
        mass_final_kg=mass1,
        mass_unit="kg per metre of depth" if sc.dim == 2 else "kg",
        n_lost=int(state.n_lost),
        n_outflow=acc["n_outflow"],
        times_s=times,
        runout_m=fronts,
        final_runout_m=fronts[-1],
        runout_farthest_particle_m=acc["farthest"],
        final_runout_farthest_particle_m=acc["farthest"][-1],
        **_scenario_metrics(setup, state, times, kinetic),
        runout_definition=gauge.definition(),
        runout_farthest_particle_definition=gauge.farthest_definition(),
        runout_front_fraction=gauge.fraction,
        # the domain face the runout runs towards, measured like the runout; a front within one cell
        # of it was stopped by the wall, not by the material (docs/output.md "Runout")
        runout_wall_m=sc.hi[gauge.axis] - gauge.origin,
        runout_capped_by_wall=bool(max(fronts[-1], acc["farthest"][-1]) >= sc.hi[gauge.axis] - gauge.origin - sc.h),
        # resolution across the deposit (docs/output.md "Runout"; the needed number: docs/validation.md)
        deposit_max_thickness_m=thick,
        deposit_cells_across=across,
        deposit_cells_definition=(
            "depth-averaged: the deposit's length along the runout axis (bins at least runout_front_fraction of the "
            "thickest) in cells"
            if shallow
            else "the deposit's largest thickness in cells"
        ),
        deposit_cells_across_needed=_metrics.DEPOSIT_CELLS_NEEDED,
        dt_limits={
            k: _jsonable(info[k])
            for k in (
                "dt_wave_s",
                "dt_viscous_s",
                "dt_limit_s",
                "wave_speed_m_s",
                "velocity_scale_m_s",
                "maxwell_G_pa",
                "mu_max_pa_s",
            )
        },
        grid_shape=list(sc.grid_shape),
        cell_size_m=sc.h,
        code_version=__version__,
        jax_backend=jax.default_backend(),
    )
    closing = [(_shallow_warning if shallow else _deposit_warning)(summary["deposit_cells_across"], thick, sc.h)]
    speed, advancing = _front_at_the_end(times, fronts, sc.h, summary["runout_wall_m"])
    summary["final_front_speed_m_s"] = speed
    creep = _tip_creep(times, fronts, sc.h, summary["time_to_rest_s"]) if shallow and sc.split_levels == 0 else None
    closing.append(creep or advancing)
    if shallow:
        H_p = _shallow.column_depth(sc, state)  # each column's depth at the end, for both checks below
        summary["sparse_volume_fraction"] = _sparse_volume_fraction(sc, state, H_p)
        summary["sparse_column_depth_m"] = _sparse_column_depth(sc, state, H_p)
        cfg = setup.cfg
        closing.append(
            _sparse_warning(
                summary["sparse_volume_fraction"], sc.split_levels, cfg["numerics.ppc"],
                depth=summary["sparse_column_depth_m"], per_level=2 ** (sc.dim - 1),  # 2^k children a split
                hazard_depth=cfg["output.hazard_depth_m"] if cfg["output.hazard_maps"] else None,
            )
        )
    if shallow and sc.split_levels > 0:
        pool = int(info.get("split_pool", 0))
        left = int(np.sum(np.asarray(_split.spare_slots(state))))
        summary["split_columns"] = {"spare_slots": pool, "slots_used": pool - left, "levels": sc.split_levels,
                                    "min_volume": sc.split_min_volume}
        k = sc.dim - 1
        # too few slots for one more split, and columns the split would split now: they were left unsplit
        wanted, share = 0, 0.0
        if left < 2**k - 1:
            unsplit = _sparse_mask(sc, state, H_p, v_min=sc.split_min_volume)
            wanted, share = int(np.sum(unsplit)), _volume_share(state, unsplit)
        summary["split_columns"]["sparse_unsplit_at_end"] = wanted
        # their share of the volume: a user weighs the remedy's cost against it (field-breach-da at one level leaves 86
        # columns unsplit, and a pool of 2 moves its front by 1 m at 1.6x the cost)
        summary["split_columns"]["sparse_unsplit_volume_fraction"] = share
        if wanted:
            closing.append(
                f"column splitting used {pool - left} of its {pool} spare slots (numerics.split_pool = "
                f"{setup.cfg['numerics.split_pool']:g}) and {wanted} column(s) sparse at the end, "
                f"{100 * share:.2g} % of the volume (split_columns.sparse_unsplit_volume_fraction), were left "
                "unsplit, so a thin tip may be under-resolved; raise numerics.split_pool (docs/depth-averaged.md, "
                "'Column splitting')"
            )
    closing = [w for w in closing if w is not None]
    summary["warnings"] = list(summary.get("warnings", [])) + closing
    return summary, closing


# depth-averaged: the share of the volume at the end in columns sparser than the grid above which a warning says
# that the grid does not resolve that layer: the accuracy the depth-averaged benchmarks are held to (5 %), as a bound
# on the volume whose depth the grid misplaces.  Measured at the end of dambreak-lab as columns (2026-12-06): 28 % at 3
# columns a cell and one level (the deposit 12 % short of its resolved length), 1.7 % at 6 columns a cell, 0.4 % at
# 3 levels, 0 at 8 columns a cell (docs/depth-averaged.md, "Creep after arrest")
SPARSE_VOLUME_WARN = 0.05


def _sparse_mask(scene, state, H_p, v_min: float = 0.0) -> np.ndarray:
    """The active columns sparser than the plan grid (``_split.sparse_columns``; ``v_min`` 0: whatever their volume)."""
    return np.asarray(_split.sparse_columns(state, H_p, k=scene.dim - 1, h=scene.h, v_min=v_min))


def _volume_share(state, mask) -> float:
    """The share of the active columns' volume in the columns ``mask`` selects (0 with no volume)."""
    vol = np.asarray(state.vol0, float) * np.asarray(state.active)
    total = float(vol.sum())
    return float(vol[mask].sum()) / total if total > 0 else 0.0


def _sparse_volume_fraction(scene, state, H_p) -> float:
    """The share of the active columns' volume in columns sparser than the plan grid at the end: depth on the grid
    below V_p / h^k (``_split.sparse_columns`` without its smallest volume), the columns whose depth the grid does not
    resolve (a split would halve them, where its levels and spare slots allow).  ``H_p``: each column's depth [m]
    (``_shallow.column_depth``)."""
    return _volume_share(state, _sparse_mask(scene, state, H_p))


def _sparse_column_depth(scene, state, H_p) -> float | None:
    """The depth [m] the sparse columns at the end would read alone, their volume over a plan cell V_p / h^k (the
    median over them; None where none is sparse): the thinnest layer those columns can resolve.  A layer thinner than
    this is read as a row of lumps about this deep, whatever h (the column's volume shrinks with the cell): on
    field-breach-da unsplit 0.8-1.0 m on a counter-slope whose resolved layer is 0.2-0.5 m (docs/depth-averaged.md,
    'The field breach with splitting')."""
    sparse = _sparse_mask(scene, state, H_p)
    if not sparse.any():
        return None
    return float(np.median(np.asarray(state.vol0, float)[sparse])) / scene.h ** (scene.dim - 1)


def _sparse_warning(
    fraction: float, levels: int, ppc: int, *, depth: float | None = None, per_level: int = 2,
    hazard_depth: float | None = None,
) -> str | None:
    """The warning for a depth-averaged run whose columns at the end leave more than ``SPARSE_VOLUME_WARN`` of the
    volume in layers thinner than the grid resolves.  ``depth``: :func:`_sparse_column_depth`, named with what one
    more level of splitting (``per_level`` = 2^k children a column) makes of it, and against ``hazard_depth``
    (output.hazard_depth_m, where hazard maps are written) when that is thinner."""
    if not fraction > SPARSE_VOLUME_WARN:
        return None
    thin = ""
    if depth is not None:
        thin = (
            f"; those columns resolve layers down to about {depth:.3g} m (the median of their volume over a plan "
            f"cell, sparse_column_depth_m; a thinner layer reads as lumps about that deep), and one more level, with room "
            f"in the pool, divides that by {per_level}"
        )
        if hazard_depth is not None and hazard_depth < depth:
            thin += (
                f"; the hazard maps' wet threshold, output.hazard_depth_m = {hazard_depth:g} m, is thinner, so their "
                "outline in that layer is not resolved"
            )
    return (
        f"{100 * fraction:.0f} % of the volume at the end is in columns spread more than a cell apart (their depth on "
        "the grid below their volume over a plan cell; sparse_volume_fraction), a layer the grid does not resolve: a "
        "deposit's tip held there stops short (measured: dambreak-lab in this formulation at 3 columns a cell and one "
        f"level, 28 %, 1.21 m against 1.33-1.37 m resolved){thin}; raise numerics.split_levels "
        f"(= {levels}) with numerics.split_pool, or numerics.ppc (= {ppc}) (docs/depth-averaged.md, 'Creep after "
        "arrest')"
    )


# the part of the run, at its end, over which the front's speed is measured
FRONT_END_FRACTION = 0.25
# "more than one cell": a front moves by whole bins of h, so one bin with rounding is not more
MORE_THAN_A_CELL = 1.01


def _advance_since(times, fronts, t_from: float):
    """(dx [m], dt [s]) of the headline front from the first saved time at or after ``t_from`` to the end; None with
    fewer than two frames there or a non-finite front at either end."""
    t, f = np.asarray(times, float), np.asarray(fronts, float)
    k = int(np.searchsorted(t, t_from))
    if k > t.size - 2 or not (np.isfinite(f[k]) and np.isfinite(f[-1])) or t[-1] <= t[k]:
        return None
    return float(f[-1] - f[k]), float(t[-1] - t[k])


def _front_at_the_end(times, fronts, h: float, wall: float) -> tuple[float | None, str | None]:
    """The headline front's mean speed [m/s] over the last ``FRONT_END_FRACTION`` of the run (None with fewer than
    two frames there), and a warning where it advanced by more than one cell h there and is not within a cell of the
    wall ``wall`` [m], measured like the runout: final_runout_m is then a snapshot of a moving front, not a deposit's
    runout."""
    if len(times) < 2:
        return None, None
    adv = _advance_since(times, fronts, times[-1] - FRONT_END_FRACTION * (times[-1] - times[0]))
    if adv is None:
        return None, None
    dx, dt = adv
    if dx <= MORE_THAN_A_CELL * h or fronts[-1] >= wall - h:
        return dx / dt, None
    return dx / dt, (
        f"the runout front was still advancing at the end of the run: {dx:.3g} m over the last {dt:.3g} s "
        f"({dx / dt:.2g} m/s, final_front_speed_m_s; more than one cell, domain.cell_size_m = {h:g} m), so "
        "final_runout_m is a moving front's, not a deposit's: raise time.t_end_s"
    )


def _tip_creep(times, fronts, h: float, time_to_rest) -> str | None:
    """A depth-averaged run without column splitting whose front advanced by more than one cell after its kinetic
    energy fell below 1 % of its peak (time_to_rest_s): the creep of a tip whose columns have spread more than a cell
    apart (docs/depth-averaged.md, 'Creep after arrest'), which splitting holds."""
    adv = None if time_to_rest is None else _advance_since(times, fronts, time_to_rest)
    if adv is None or adv[0] <= MORE_THAN_A_CELL * h:
        return None
    dx, dt = adv
    return (
        f"the runout front advanced {dx:.3g} m in the {dt:.3g} s after the kinetic energy fell below 1 % of its peak "
        f"(time_to_rest_s = {time_to_rest:.3g} s; {dx / dt:.2g} m/s, more than one cell, domain.cell_size_m = {h:g} m): "
        "in the depth-averaged model that is the creep of a tip whose columns have spread more than a cell apart, not "
        "the material, and final_runout_m grows with time.t_end_s (docs/depth-averaged.md, 'Creep after arrest'); "
        f"column splitting (numerics.split_levels = {SCHEMA['numerics.split_levels'].default}, the default this run "
        "turned off) holds it (measured: dambreak-lab in this formulation creeps into its wall at 2 m without it and "
        "rests at 1.21 m with one level, 1.35 m with three)"
    )


def _deposit_warning(cells: float, thick: float, h: float) -> str | None:
    """The warning for a final deposit fewer than ``_metrics.DEPOSIT_CELLS_NEEDED`` cells thick."""
    if not 0 < cells < _metrics.DEPOSIT_CELLS_NEEDED:
        return None
    return (
        f"the final deposit is {cells:.1f} cells thick at its thickest point "
        f"(deposit_cells_across; {thick:.3g} m at domain.cell_size_m = {h:g} m); the convergence benchmark "
        f"needs >= {_metrics.DEPOSIT_CELLS_NEEDED} for a runout within about 5 % (docs/validation.md, 'Convergence "
        f"benchmark'): set domain.cell_size_m <= {thick / _metrics.DEPOSIT_CELLS_NEEDED:.3g} m, the cheapest remedy "
        "that converges (docs/validation.md, 'Depth resolution': more particles per cell do not pay; a domain.hi_m "
        "cropped to where the material goes saves the grid's few per cent; boundary.slip_length_m = "
        f"{0.25 * h:.3g} m (h/4) cut the shortfall by 15-30 % there at no cost, but changes the bed's physics)"
    )


def _shallow_warning(cells: float, thick: float, h: float) -> str | None:
    """The depth-averaged formulation's warning for a deposit fewer than ``_metrics.DEPOSIT_CELLS_NEEDED``
    cells long along the flow (its depth is not resolved by cells: each particle is a column)."""
    if not 0 < cells < _metrics.DEPOSIT_CELLS_NEEDED:
        return None
    return (
        f"the final deposit is {cells:.1f} cells long along the runout axis (deposit_cells_across, depth-averaged "
        f"formulation; domain.cell_size_m = {h:g} m): fewer than {_metrics.DEPOSIT_CELLS_NEEDED} cells do not resolve "
        f"its shape in plan: set domain.cell_size_m <= {cells * h / _metrics.DEPOSIT_CELLS_NEEDED:.3g} m"
    )
