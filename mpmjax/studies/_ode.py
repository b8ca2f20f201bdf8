"""The one way the studies' reference solutions call diffrax: an adaptive solve from t = 0, saved at given times."""

from __future__ import annotations

import diffrax


def solve_saved(rhs, solver, y0, ts, dt0, args, *, rtol: float, atol, max_steps: int):
    """``y' = rhs(t, y, args)`` from t = 0 to ``ts[-1]`` with ``solver`` under a PID step-size controller
    (``rtol``, ``atol``), first step ``dt0``: (the solution at ``ts``, the number of steps taken)."""
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(rhs),
        solver,
        0.0,
        ts[-1],
        dt0,
        y0,
        args=args,
        saveat=diffrax.SaveAt(ts=ts),
        stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
        max_steps=max_steps,
    )
    return sol.ys, sol.stats["num_steps"]
