"""The fit loop: Levenberg-Marquardt (optimistix), L-BFGS or Adam (optax), one compiled model, multi-start.

``fit(experiments, pset)`` minimises the joint loss L = sum_e w_e mean(r_e^2) (see
``calibration.experiments``) over the unconstrained vector z of ``pset``
(``calibration.params.ParameterSet``).  The model's value and gradient are compiled once
(:class:`Objective`) and called from the jitted optimiser update through ``jax.pure_callback``;
the starts step in lockstep on the host, one update call each per iteration, sharing that
compiled model.  The host-side loop shows progress and stops each start early.

Starts: start 0 is the specified initial guess; start k > 0 multiplies each free
parameter by exp(s N(0, 1)) (s = ``start_spread``, default ln 2: a factor of 2 at one
standard deviation), clipped inside its bounds.

Stopping (per start; the loop ends when every start has stopped or ``max_iter``):

* converged: the loss fell by less than ``rtol`` (relative) over the last ``patience``
  iterations, or the gradient norm in z is below ``gtol``, or the loss is below ``atol``
  (e.g. an exact synthetic fit); ``lm``: also its Gauss-Newton test below;
* not converged: ``max_iter`` reached first.

Methods: ``lm`` (the default: Levenberg-Marquardt, ``optimistix.LevenbergMarquardt``, on
the residual vector R = concat_e sqrt(w_e / N_e) r_e, so that L = |R|^2: one step evaluates R
and its Jacobian in forward mode, one tangent per parameter, which costs what a forward-mode gradient costs, and
Gauss-Newton steps need a few iterations where L-BFGS needs tens; measured in
docs/calibration.md "Speed"), ``lbfgs`` (``optax.lbfgs`` with its zoom line search: a
quasi-Newton method for any smooth loss, tens of iterations) and ``adam``
(``optax.adam(learning_rate)``; robust to kinks, needs more iterations).

``lm`` also stops (per start) when the full Gauss-Newton step from the last accepted point
predicts a relative decrease of L of at most ``rtol`` (|P R|^2 / |R|^2, P the projection onto
the Jacobian's columns: the residual is orthogonal to every direction the parameters can move
it, to within rtol); that is how a smooth fit ends, in a step or two after the loss stops
falling.  The ``patience`` test above ends the fits whose loss stalls while the linear model
still predicts a decrease (the trust region rejects every step: measured on the README's
example, a twin at h = 0.02 m fitted to data from a twice finer grid, float64, where the
derivative of the run no longer describes the loss at the step's scale).  One iteration is
one step of the solver (one model evaluation, accepted or rejected).
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
import optimistix as optx
from jax.experimental import multihost_utils

import mpmjax

from .experiments import joint_loss, joint_residuals

__all__ = [
    "DEFAULT_STARTS",
    "MULTISTART_MIN_PARAMS",
    "FitResult",
    "Objective",
    "default_starts",
    "fit",
    "forward_mode_gradient",
    "loss_function",
]

# multi-start by default (issue 32): from this many free parameters on, ``calibrate`` runs
# DEFAULT_STARTS starts (the first at the initial values, the others a random factor e^{N(0, ln 2)}
# away) in lockstep at the first level, and reports every distinct optimum
# (``calibration.optima``): with three or more parameters the loss has had more than one basin
# (issue 32: lambda0 at 0.06 and at 1.33 in a five-parameter fit).
MULTISTART_MIN_PARAMS = 3
DEFAULT_STARTS = 4


def default_starts(n_free: int) -> int:
    """The number of starts ``calibrate`` runs when not told: DEFAULT_STARTS for
    MULTISTART_MIN_PARAMS or more free parameters, else 1."""
    return DEFAULT_STARTS if n_free >= MULTISTART_MIN_PARAMS else 1


class FitResult(NamedTuple):
    """Result of :func:`fit`.

    params: best fitted values, name -> float [SI] (free parameters; fixed ones are in
    ``pset``); loss_initial: loss at the initial guess (start 0); loss_final: loss at
    ``params``; history: (iterations + 1, n_starts) loss of each start before each
    iteration and at the end; iterations: iterations run; wall_s: wall time of the loop
    (compilation included) [s]; compile_s: wall time of compiling the model (value and
    gradient, :class:`Objective`) [s]; converged:
    whether the best start met a convergence criterion; reason: which; best_start: its
    index; starts: initial values per start; finals: fitted values per start;
    final_losses: final loss per start; gradient: "forward" or "reverse" (how it was computed);
    cpu_s, compile_cpu_s: CPU time of the loop and of the compilation [s] (``time.process_time``,
    all threads); evaluations: {"value", "value_and_grad"}, model evaluations (one start each);
    run_s: wall time spent running the compiled model (the rest of ``wall_s`` is compilation and
    the optimiser's own work) [s]; residuals_initial, residuals_final (``lm`` only, else None):
    per start, (R, dR/dz) at its starting point and at its final point (R = the weighted residual
    vector whose squared norm is the loss, ``residual_function``; None for a start another
    process ran), what Levenberg-Marquardt evaluated there: the numerical std at fixed parameters
    (``calibration.multilevel``) and the distinct optima of a multi-start fit read them.
    """

    params: dict
    loss_initial: float
    loss_final: float
    history: np.ndarray
    iterations: int
    wall_s: float
    compile_s: float
    converged: bool
    reason: str
    best_start: int
    starts: list
    finals: list
    final_losses: np.ndarray
    gradient: str = "reverse"
    cpu_s: float = float("nan")
    compile_cpu_s: float = float("nan")
    evaluations: dict | None = None
    run_s: float = float("nan")
    residuals_initial: list | None = None
    residuals_final: list | None = None


# "auto" gradient: forward mode up to this many free parameters (measured break-even ~2.7, see fit())
FORWARD_MODE_MAX_PARAMS = 2


def loss_function(experiments, pset, gradient: str = "reverse"):
    """z -> L (the joint loss of the experiments at the parameters ``pset.theta(z)``).

    gradient: how ``jax.grad`` of the returned function is computed: ``"reverse"`` (one
    reverse pass through the MPM scan) or ``"forward"`` (one forward-mode tangent per free
    parameter, batched with ``vmap``, behind a ``jax.custom_vjp``: cheaper for few parameters,
    see :func:`fit`)."""

    def loss_z(z):
        return joint_loss(experiments, pset.values(pset.theta(z)))

    if gradient == "reverse":
        return loss_z
    if gradient != "forward":
        raise ValueError(f"gradient = {gradient!r} is invalid; allowed: 'reverse', 'forward' or 'auto'")
    return forward_mode_gradient(loss_z)


def residual_function(experiments, pset):
    """z -> R, the residual vector whose squared norm is the joint loss: R = concat_e
    sqrt(w_e / N_e) r_e (``calibration.experiments.joint_loss``: L = sum_e w_e mean(r_e^2))."""

    def res_z(z):
        rs = joint_residuals(experiments, pset.values(pset.theta(z)))
        return jnp.concatenate(
            [jnp.sqrt(e.weight / r.size) * jnp.ravel(r) for e, r in zip(experiments, rs, strict=True)]
        )

    return res_z


def forward_jacobian(f):
    """z -> (f(z), df/dz) for a vector f, in forward mode: one ``jax.jvp`` tangent per
    parameter, batched by ``vmap`` (the primal is computed once).  Traced with
    ``mpmjax.flat_transfers``: with the tangents batched and the stencil not, the CPU's row
    transfers cost more than the flat ones."""

    def rj(z):
        with mpmjax.flat_transfers():
            vals, tans = jax.vmap(lambda t: jax.jvp(f, (z,), (t,)))(jnp.eye(z.shape[-1], dtype=z.dtype))
        return vals[0], tans.T

    return rj


def forward_value_and_grad(f):
    """z -> (f(z), df/dz) for a scalar f in forward mode: :func:`forward_jacobian`, whose
    Jacobian of a scalar is its gradient."""
    return forward_jacobian(f)


def forward_mode_gradient(f):
    """``f(z) -> scalar`` (z a 1-D vector) whose reverse-mode rule is computed in forward mode:
    ``jax.jvp`` along every unit vector, batched by ``vmap`` (the primal is computed once).
    A reverse pass through the MPM scan costs about 4.3 forward runs on CPU (docs/calibration.md),
    a tangent about 1.5 more, so for one or two parameters this is the cheaper gradient; the
    values agree to rounding."""

    value_and_grad = forward_value_and_grad(f)

    @jax.custom_vjp
    def g(z):
        return f(z)

    def g_bwd(grad, ct):
        return (ct * grad,)

    g.defvjp(value_and_grad, g_bwd)
    return g


def _starts(pset, n_starts, spread, seed, dtype):
    rng = np.random.default_rng(seed)
    zs = [np.asarray(pset.z0(dtype))]
    thetas = [{k: pset.specs[k].init for k in pset.free}]
    for _ in range(1, n_starts):
        th = {}
        for k in pset.free:
            s = pset.specs[k]
            v = (
                s.init * math.exp(spread * rng.standard_normal())
                if s.init > 0
                else s.init + spread * rng.standard_normal()
            )
            lo = s.lo if s.lo is not None else (0.0 if s.transform == "softplus" else -math.inf)
            hi = s.hi if s.hi is not None else math.inf
            # keep a start strictly inside the bounds (1e-3 of the log- or linear range)
            if s.transform == "log" and s.lo is not None:
                a, b = math.log(lo), math.log(hi)
                v = math.exp(min(max(math.log(v), a + 1e-3 * (b - a)), b - 1e-3 * (b - a)))
            elif math.isfinite(lo) and math.isfinite(hi):
                v = min(max(v, lo + 1e-3 * (hi - lo)), hi - 1e-3 * (hi - lo))
            elif math.isfinite(lo):
                v = max(v, lo + 1e-6 * max(abs(lo), 1.0))
            th[k] = v
        thetas.append(th)
        zs.append(np.asarray(pset.z_of_theta(th, dtype)))
    return jnp.asarray(np.stack(zs), dtype), thetas


def _default_callback(stream=sys.stderr):
    t0 = time.perf_counter()

    def cb(it, max_iter, losses, best_theta, active):
        el = time.perf_counter() - t0
        vals = ", ".join(f"{k}={v:.4g}" for k, v in best_theta.items())
        stream.write(
            f"calibrate: iteration {it:4d}/{max_iter} loss {float(np.min(losses)):.4e} "
            f"({int(np.sum(active))} of {len(losses)} start(s) running) {vals}  elapsed {el:6.1f} s\n"
        )
        stream.flush()

    return cb


class Objective:
    """The loss of a fit as separately compiled programs, called from the optimiser through
    ``jax.pure_callback``.

    ``loss_z(z) -> L`` (z: the (k,) vector of transformed parameters) is compiled twice, on
    first use: as the value alone and as value and gradient (``gradient``: ``"forward"``, one
    ``jax.jvp`` tangent per parameter batched by ``vmap``, or ``"reverse"``, ``jax.grad``).
    :meth:`traced` returns a JAX function of z whose value and ``jax.grad`` call those programs
    on the host, so the optimiser's own program (optax's L-BFGS update with its zoom line search)
    holds only callbacks, compiles in seconds, and every line-search trial reuses the one
    compiled model.

    Why (measured on the joint twin, docs/calibration.md "Speed"): inlined, the update held three
    copies of the model's value-and-gradient (``optax.value_and_grad_from_state`` and the two
    branches of the zoom line search's ``lax.cond``); under the ``vmap`` over starts every
    ``cond`` becomes a select that runs both branches, so each iteration evaluated 1 + 2 x
    (line-search steps) gradients instead of (line-search steps), and XLA compiled the whole
    program (15 min for five parameters).

    ``residuals_z(z) -> R`` (optional, for ``method="lm"``): the residual vector, compiled with
    its forward-mode Jacobian as a third program (:meth:`residuals_and_jacobian`,
    :meth:`traced_residuals`).

    Counters: ``evaluations`` {"value", "value_and_grad"[, "residuals_and_jacobian"]} (calls, one
    start each), ``compile_s``
    / ``compile_cpu_s`` (wall / CPU time of compiling the two programs [s]), ``run_s`` /
    ``run_cpu_s`` (of running them [s]).
    """

    def __init__(self, loss_z, gradient: str = "forward", residuals_z=None):
        if gradient not in ("forward", "reverse"):
            raise ValueError(f"gradient = {gradient!r} is invalid; allowed: 'reverse', 'forward' or 'auto'")
        self.gradient = gradient
        vg = forward_value_and_grad(loss_z) if gradient == "forward" else jax.value_and_grad(loss_z)
        self._fns = {"value": jax.jit(loss_z), "value_and_grad": jax.jit(vg)}
        self.evaluations = {"value": 0, "value_and_grad": 0}
        if residuals_z is not None:
            # Levenberg-Marquardt: the residual vector and its Jacobian, in forward mode, one program
            self._fns["residuals_and_jacobian"] = jax.jit(forward_jacobian(residuals_z))
            self._residuals_z = residuals_z
            self.evaluations["residuals_and_jacobian"] = 0
        self._compiled = {}
        self.compile_s = self.compile_cpu_s = self.run_s = self.run_cpu_s = 0.0

    def _call(self, kind, z):
        z = np.asarray(z)
        key = (kind, z.shape, z.dtype)
        if key not in self._compiled:
            w0, c0 = time.perf_counter(), time.process_time()
            self._compiled[key] = self._fns[kind].lower(z).compile()
            self.compile_s += time.perf_counter() - w0
            self.compile_cpu_s += time.process_time() - c0
        w0, c0 = time.perf_counter(), time.process_time()
        out = jax.block_until_ready(self._compiled[key](z))
        self.run_s += time.perf_counter() - w0
        self.run_cpu_s += time.process_time() - c0
        self.evaluations[kind] += 1
        return out

    def value(self, z):
        """L at one z (numpy scalar)."""
        return np.asarray(self._call("value", z))

    def value_and_grad(self, z):
        """(L, dL/dz) at one z (numpy)."""
        v, g = self._call("value_and_grad", z)
        return np.asarray(v), np.asarray(g)

    def residuals_and_jacobian(self, z):
        """(R, dR/dz) at one z (numpy)."""
        r, j = self._call("residuals_and_jacobian", z)
        return np.asarray(r), np.asarray(j)

    def traced_residuals(self, z_like):
        """z -> R as a JAX function (for optimistix) whose value and ``jax.jacrev`` come from one
        host callback to the compiled residuals-and-Jacobian program (the solver asks for the
        Jacobian at every point it evaluates, so nothing is wasted)."""
        rs = jax.eval_shape(self._residuals_z, z_like)
        js = jax.ShapeDtypeStruct(rs.shape + z_like.shape, z_like.dtype)

        @jax.custom_vjp
        def r(z):
            return jax.pure_callback(lambda zz: self.residuals_and_jacobian(zz)[0], rs, z)

        def r_fwd(z):
            return jax.pure_callback(self.residuals_and_jacobian, (rs, js), z)

        def r_bwd(j, ct):
            return (ct @ j,)

        r.defvjp(r_fwd, r_bwd)
        return r

    def traced_value_and_grad(self, z):
        """(L, dL/dz) at a traced z, by a host callback to the compiled value-and-gradient."""
        shapes = jax.ShapeDtypeStruct((), z.dtype), jax.ShapeDtypeStruct(z.shape, z.dtype)
        return jax.pure_callback(self.value_and_grad, shapes, z)

    def traced(self):
        """z -> L as a JAX function (for optax) whose value and gradient are host callbacks to
        the compiled programs (not to be ``vmap``-ped: one start per call)."""

        @jax.custom_vjp
        def f(z):
            return jax.pure_callback(self.value, jax.ShapeDtypeStruct((), z.dtype), z)

        def f_fwd(z):
            return self.traced_value_and_grad(z)

        def f_bwd(g, ct):
            return (ct * g,)

        f.defvjp(f_fwd, f_bwd)
        return f


def _exchange(mine, zs, loss, gn, *extra):
    """Every start's z, loss and gradient norm (and any ``extra`` per-start arrays) on every
    process of a ``jax.distributed`` job (``mine``: the starts this process runs; the others'
    entries are gathered from their owners, start k on process k mod P); unchanged in a
    single-process run."""
    if jax.process_count() == 1:
        return (zs, loss, gn, *extra)
    z = np.where(mine[:, None], np.stack(zs), 0.0)
    got = multihost_utils.process_allgather(
        {"z": z, "loss": np.where(mine, loss, 0.0), "gn": np.where(mine, gn, 0.0),
         "extra": [np.where(mine, np.asarray(e, float), 0.0) for e in extra]}
    )
    k = np.arange(len(mine))
    owner = k % jax.process_count()
    z = np.asarray(got["z"])[owner, k]
    ex = [np.asarray(e)[owner, k] for e in got["extra"]]
    return (list(z), np.asarray(got["loss"])[owner, k], np.asarray(got["gn"])[owner, k], *ex)


def _optimiser(method, obj, f, pset, dtype, learning_rate):
    """``(opt, update)``: the optimiser (its ``init``) and one iteration ``update(z, s, v, g)`` of
    ``fit``'s method (``adam``, ``lbfgs`` or ``lm``; LM's update also returns the relative decrease
    its Gauss-Newton step predicts)."""
    if method == "adam":
        opt = optax.adam(learning_rate)

        def update(z, s, v, g):
            u, s = opt.update(g, s, z)
            nz = optax.apply_updates(z, u)
            nv, ng = obj.traced_value_and_grad(nz)
            return nz, s, nv, ng

    elif method == "lbfgs":
        opt = optax.lbfgs()

        def update(z, s, v, g):
            # the line search evaluates the loss and gradient at the accepted step and keeps them in
            # its state (what optax.value_and_grad_from_state reads): the next iteration reuses them
            u, ns = opt.update(g, s, z, value=v, grad=g, value_fn=f)
            nz = optax.apply_updates(z, u)
            nv, ng = optax.tree.get(ns, "value"), optax.tree.get(ns, "grad")
            # a converged line search may return a non-finite step: keep the last iterate
            ok = jnp.all(jnp.isfinite(nz)) & jnp.isfinite(nv)
            return jax.tree.map(lambda a, b: jnp.where(ok, a, b), (nz, ns, nv, ng), (z, s, v, g))

    else:
        z_like = jax.ShapeDtypeStruct((len(pset.free),), dtype)
        res = obj.traced_residuals(z_like)
        r_struct = jax.eval_shape(res, z_like)

        def lm_fn(y, args):
            return res(y), None

        # optimistix's own (Cauchy) termination is not used: the loop below stops each start
        solver = optx.LevenbergMarquardt(rtol=0.0, atol=0.0)
        opts = {"jac": "bwd"}  # jax.jacrev of the callback: its custom_vjp returns the Jacobian computed with R

        class _Opt:  # the optax-like init the loop calls
            @staticmethod
            def init(z):
                return solver.init(lm_fn, z, None, opts, r_struct, None, frozenset())

        opt = _Opt

        def update(z, s, v, g):
            # one solver step: R and J at the proposed point, accepted or rejected by the trust region;
            # returns the last accepted point, its loss |R|^2 and gradient 2 J^T R, and the relative
            # decrease the full Gauss-Newton step predicts from there
            ny, ns, _ = solver.step(lm_fn, z, None, opts, s, frozenset())
            r, jac = ns.f_info.residual, ns.f_info.jac.as_matrix()
            nv = jnp.sum(r**2)
            dz = jnp.linalg.lstsq(jac, -r)[0]
            pred = jnp.sum((jac @ dz) ** 2) / jnp.maximum(nv, jnp.finfo(nv.dtype).tiny)
            return ny, ns, nv, 2.0 * jac.T @ r, pred

    return opt, update


def fit(
    experiments,
    pset,
    *,
    method: str = "lm",
    max_iter: int = 100,
    learning_rate: float = 0.05,
    rtol: float = 1e-4,
    gtol: float = 1e-8,
    atol: float = 0.0,
    patience: int = 5,
    n_starts: int = 1,
    start_spread: float = math.log(2.0),
    seed: int = 0,
    progress: Any = True,
    gradient: str = "auto",
    z_starts=None,
) -> FitResult:
    """Fit the free parameters of ``pset`` to ``experiments`` (see the module docstring).

    progress: True (a line per iteration on stderr), False, or a callable
    ``cb(iteration, max_iter, losses, best_theta, running)``.

    gradient: ``"reverse"``, ``"forward"`` (see :func:`forward_mode_gradient`) or ``"auto"``
    (default): forward mode for up to ``FORWARD_MODE_MAX_PARAMS`` free parameters.  Measured on
    the twin scene (2-core CPU, float64; benchmarks/gradient/gradient_modes.py): value and gradient cost
    3.1-3.3 loss evaluations in forward mode against 4.2-4.4 in reverse mode for 2 parameters,
    7.7 against 4.2-4.4 for 5; about 0.1 + 1.5 k against 4.3, so forward mode wins up to k = 2.
    (Before the reverse pass's fusion boundaries and kept states, docs/performance.md: reverse
    mode cost 7.6-8.2 and forward mode won up to k = 8.)

    The model is compiled once (:class:`Objective`) and called from the optimiser's update, which
    is compiled apart; the starts step in lockstep, one update call each (a stopped start costs
    nothing more).

    z_starts: optional (n_starts, len(pset.free)) array of starting points in z (replaces the
    generated starts and ``n_starts``; e.g. warm starts, or the grid of a profile likelihood,
    ``calibration.profile``).
    """
    if method not in ("lbfgs", "adam", "lm"):
        raise ValueError(f"method = {method!r} is invalid; allowed: 'lbfgs', 'lm' or 'adam'")
    for nm, v, lo in (("max_iter", max_iter, 1), ("n_starts", n_starts, 1), ("patience", patience, 1)):
        if int(v) != v or v < lo:
            raise ValueError(f"{nm} = {v!r} is invalid; allowed range: integer >= {lo}")
    if not (learning_rate > 0 and math.isfinite(learning_rate)):
        raise ValueError(f"learning_rate = {learning_rate!r}; allowed range: > 0")
    dtype = jnp.dtype(experiments[0].setup.scene.dtype) if hasattr(experiments[0], "setup") else jnp.float64
    if method == "lm":
        # LM needs the residuals' whole Jacobian: forward mode gives it in one tangent per
        # parameter, reverse mode would need one pass per residual (hundreds)
        if gradient == "reverse":
            raise ValueError(
                "gradient = 'reverse' is invalid with method = 'lm'; allowed: 'forward' or 'auto' (the "
                "Jacobian of the residuals is computed in forward mode, one tangent per parameter)"
            )
        gradient = "forward"
    elif gradient == "auto":
        gradient = "forward" if len(pset.free) <= FORWARD_MODE_MAX_PARAMS else "reverse"
    obj = Objective(
        loss_function(experiments, pset, "reverse"),
        gradient,
        residual_function(experiments, pset) if method == "lm" else None,
    )
    f = obj.traced()
    lm = method == "lm"

    opt, update = _optimiser(method, obj, f, pset, dtype, learning_rate)
    jupdate = jax.jit(update)
    if z_starts is None:
        z, start_thetas = _starts(pset, int(n_starts), float(start_spread), seed, dtype)
    else:
        z = jnp.atleast_2d(jnp.asarray(z_starts, dtype))
        if z.ndim != 2 or z.shape[1] != len(pset.free):
            raise ValueError(f"z_starts has shape {z.shape}; expected (starts, {len(pset.free)})")
        start_thetas = [{k: float(v) for k, v in pset.theta(zi).items()} for zi in z]
    n = z.shape[0]
    zs = [np.asarray(zi) for zi in z]
    # the optimiser state as the update returns it: optax's initial state holds weak-typed scalars
    # (L-BFGS: its line-search info) that come back strongly typed, and a change of weak type
    # retraces and recompiles the update on the second iteration
    states = [jax.tree.map(lambda a: a.astype(a.dtype), opt.init(jnp.asarray(zi))) for zi in zs]
    cb = _default_callback() if progress is True else (progress or None)
    running = np.ones(n, bool)
    reason = np.array(["max_iter"] * n, dtype=object)
    t0, c0 = time.perf_counter(), time.process_time()
    # in a jax.distributed job start k runs on process k mod P; _exchange gives every process every
    # start's z, loss and gradient norm after each iteration, so all take the same decisions
    mine = np.arange(n) % jax.process_count() == jax.process_index()
    nan_vg = (np.asarray(np.nan), np.full(len(pset.free), np.nan))
    # LM's Gauss-Newton prediction of the relative decrease per start (inf: none, other methods)
    pred = np.full(n, np.inf)
    rj_initial = [None] * n

    def _rj(state):  # LM's (R, dR/dz) at its last accepted point
        return np.asarray(state.f_info.residual), np.asarray(state.f_info.jac.as_matrix())

    if lm:
        # LM's first step evaluates R and J at the start (always accepted) and proposes the next point
        vgs = [nan_vg] * n
        for k in np.flatnonzero(mine):
            out = jupdate(jnp.asarray(zs[k]), states[k], jnp.asarray(np.nan), jnp.asarray(zs[k]))
            zs[k], states[k], vgs[k], pred[k] = (
                np.asarray(out[0]), out[1], (np.asarray(out[2]), np.asarray(out[3])), float(out[4]))
            rj_initial[k] = _rj(states[k])
    else:
        vgs = [obj.value_and_grad(zi) if mine[k] else nan_vg for k, zi in enumerate(zs)]
    loss = np.array([float(v) for v, _ in vgs])
    zs, loss, _ = _exchange(mine, zs, loss, np.zeros(n))
    hist = [loss.copy()]
    if not np.all(np.isfinite(loss)):
        bad = int(np.flatnonzero(~np.isfinite(loss))[0])
        raise FloatingPointError(
            f"calibration: the loss is {loss[bad]} at start {bad}, parameters "
            f"{ {k: float(v) for k, v in pset.theta(jnp.asarray(zs[bad])).items()} }: the run produced "
            "non-finite heights"
        )
    it = 0
    for it in range(1, int(max_iter) + 1):
        for k in np.flatnonzero(running & mine):
            out = jupdate(jnp.asarray(zs[k]), states[k], jnp.asarray(vgs[k][0]), jnp.asarray(vgs[k][1]))
            zs[k], states[k] = np.asarray(out[0]), out[1]
            vgs[k] = (np.asarray(out[2]), np.asarray(out[3]))
            if lm:
                pred[k] = float(out[4])
        loss = np.array([float(v) for v, _ in vgs])
        gn = np.array([float(np.linalg.norm(g)) for _, g in vgs])
        # the convergence inputs travel with the gradient norm: every process decides alike
        zs, loss, gn, pred = _exchange(mine, zs, loss, gn, pred)
        if not np.all(np.isfinite(loss[running])):
            bad = int(np.flatnonzero(~np.isfinite(loss) & running)[0])
            raise FloatingPointError(
                f"calibration: the loss is {loss[bad]} at start {bad}, iteration {it}, parameters "
                f"{ {k: float(v) for k, v in pset.theta(jnp.asarray(zs[bad])).items()} }: the run produced "
                "non-finite heights"
            )
        hist.append(loss.copy())
        H = np.asarray(hist)
        for k in np.flatnonzero(running):
            if loss[k] <= atol:
                running[k], reason[k] = False, "atol"
            elif gn[k] < gtol:
                running[k], reason[k] = False, "gtol"
            elif pred[k] <= rtol:
                # the full Gauss-Newton step from the last accepted point predicts a relative
                # decrease <= rtol: no step can lower the loss by more, to first order (the
                # residual is orthogonal to the Jacobian's columns to within rtol)
                running[k], reason[k] = False, "rtol"
            elif it >= patience:
                old = H[-1 - patience, k]
                if old - loss[k] <= rtol * abs(old):
                    running[k], reason[k] = False, "rtol"
        if cb is not None:
            b = int(np.argmin(loss))
            cb(it, int(max_iter), loss, {k: float(v) for k, v in pset.theta(jnp.asarray(zs[b])).items()}, running)
        if not running.any():
            break
    wall = time.perf_counter() - t0
    final = hist[-1]
    best = int(np.nanargmin(final))
    finals = [{k: float(v) for k, v in pset.theta(jnp.asarray(zi)).items()} for zi in zs]
    return FitResult(
        params=finals[best],
        loss_initial=float(hist[0][0]),
        loss_final=float(final[best]),
        history=np.asarray(hist),
        iterations=it,
        wall_s=wall,
        compile_s=obj.compile_s,
        converged=reason[best] != "max_iter",
        reason=str(reason[best]),
        best_start=best,
        starts=start_thetas,
        finals=finals,
        final_losses=final,
        gradient=gradient,
        cpu_s=time.process_time() - c0,
        compile_cpu_s=obj.compile_cpu_s,
        evaluations=dict(obj.evaluations),
        run_s=obj.run_s,
        residuals_initial=rj_initial if lm else None,
        residuals_final=[_rj(states[k]) if mine[k] else None for k in range(n)] if lm else None,
    )
