"""The inertial Bingham slump of ``mpmjax validate`` (``converge.py``'s: tau_y 82 Pa, mu 7 Pa s, a 0.2 m block, ppc 2)
at several cell sizes and pressures, one JSON line a run (docs/voids.md, "The inertial slump").

Its reference, the front x_f of the static lubrication profile holding the released area, is read with the run's own
front definition (``exact_front_by_definition_m``: 1.2 % behind x_f at 1.25 cm).  A deposit with voids covers more
area than its particles' volume, so each line also gives the area under its free surface
(``converge.slump_occupied_area``) over its rest volume and over sum J V0, and the run's front against the same
reference for that occupied area.

    .venv/bin/python benchmarks/accuracy/inertial_slump_h.py incompressible,explicit 0.0125,0.00625,0.003125 [t_end_s [KEY=VALUE ...]]

KEY=VALUE: further scene overrides (numbers as numbers), e.g. material.papanastasiou_m_s=1e5,
numerics.maxwell_shear_modulus_pa=2e5, numerics.dtype=float64.
"""
import json
import sys

from mpmjax.studies import converge

pressures = sys.argv[1].split(",")
cells = [float(a) for a in sys.argv[2].split(",")]
t_end = float(sys.argv[3]) if len(sys.argv) > 3 else 6.0


def _value(v):
    try:
        return float(v)
    except ValueError:
        return v


extra = {k: _value(v) for k, v in (a.split("=", 1) for a in sys.argv[4:])}
for h in cells:
    for pressure in pressures:
        ov = {"domain.cell_size_m": h, "time.t_end_s": t_end, "time.n_frames": 12, "numerics.pressure": pressure, **extra}
        r = converge.run_one("slump", ov)
        out = {k: r.get(k) for k in ("status", "reason", "n_steps", "n_particles", "cpu_s", "runout_m", "runout_farthest_m", "max_speed_m_s")}
        if r["status"] == "ok":
            converge.slump_errors(r, h)
            out.update({k: r[k] for k in ("exact_front_m", "exact_front_by_definition_m", "front_err_pct", "farthest_err_pct", "profile_err_pct")})
            # validate's check: the front against the reference read as the run's front, relative to that reference
            out["front_vs_reference_pct"] = 100.0 * (r["runout_m"] / r["exact_front_by_definition_m"] - 1.0)
            out.update(
                occupied_over_rest=r["occupied_area_m2"] / r["area_m2"],
                occupied_over_volume=r["occupied_area_m2"] / r["volume_m2"],
                volume_over_rest=r["volume_m2"] / r["area_m2"],
                occupied_front_by_definition_m=r["occupied_front_by_definition_m"],
                front_vs_occupied_reference_pct=100.0 * (r["runout_m"] / r["occupied_front_by_definition_m"] - 1.0),
            )
        print(json.dumps(dict(pressure=pressure, h_m=h, t_end_s=t_end, overrides=extra, **out)), flush=True)
