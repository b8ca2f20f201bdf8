"""mpmjax: a differentiable Material Point Method for thixotropic mine tailings, in JAX.

Public API (modules are private; names are re-exported here):

* scenes: ``load_scene``, ``validate`` (nested dict -> flat validated dict), ``build``,
  ``builtin_scenes``, ``SceneError``, ``SCHEMA``
* the step: ``make_step``, ``make_p2g``, ``Scene``, ``State``, ``Params`` (with ``Basal``), ``init_state``;
  ``flat_transfers`` (a context for forward-mode Jacobians on the CPU)
* time integration: ``simulate``, ``run``, ``make_advance``, ``Frame``; chunked host-side
  stepping: ``make_steps`` (any number of steps, one program), ``Pacer``, ``run_chunked``,
  ``chunkable``; ``check_interrupted`` (a signal whose exception was dropped, ``_received``)
* rheology: ``Newtonian``, ``Bingham``, ``HerschelBulkley``, ``Coussot`` and their
  parameter NamedTuples; adding a law: ``Law``, ``Param``, ``Option``, ``Internal``,
  ``register_law``, ``unregister_law``; ``material_parameters()`` (name -> ``Param``: scene
  key, unit, default, range, calibration bounds), ``law_of(params)``; what a fit or a sweep can
  vary by name, material and basal friction alike: ``fit_parameters``, ``unused_parameters``, ``basal_parameters``,
  ``replace_parameters``, ``parameter_value``
* time step: ``time_step_limits``; cost before a run is built: ``check_memory`` (refuses with
  ``MemoryRefused``, a ``SceneError``), ``STEPS_WARN`` and ``estimate_run_time_s``
* observables: ``runout``; differentiable ``height_profile``, ``smooth_front``,
  ``deposited_volume``, ``particle_volume``, ``gaussian_kernel``; metrics ``kinetic_energy``,
  ``time_to_rest``
* files: ``atomic_write_text``, ``config_hash``
* runs on disk (what ``mpmjax run`` does): ``run_scene`` (result.h5, summary.json, plots,
  checkpoint and resume), ``RunFailure`` (a failed health check), ``Interrupted`` (SIGINT/SIGTERM)
* plots of a saved run: the ``plotting`` module (``particles``, ``profiles``,
  ``runout_vs_time``, ``animate``)
"""

from ._received import hold_startup_signals

hold_startup_signals()  # the program: Ctrl-C / SIGTERM during the imports below are noted, not lost (_received)

from ._fusion import prefer_xla_reductions  # noqa: E402

prefer_xla_reductions()  # before any JAX computation starts the backends (docs/performance.md, "Fusion boundaries")

from . import plotting  # noqa: E402  (imports matplotlib only when a plot is made)
from ._build import STEPS_WARN, Setup, build, estimate_run_time_s, make_params, time_step_limits
from ._constitutive import tait_pressure
from ._driver import Interrupted, MemoryRefused, check_memory, run_scene
from ._health import RunFailure
from ._io import atomic_write_text, config_hash
from ._metrics import kinetic_energy, time_to_rest
from ._observables import (
    FRONT_FRACTION,
    deposited_volume,
    free_surface_front,
    gaussian_kernel,
    height_profile,
    particle_volume,
    runout,
    smooth_front,
)
from ._received import check as check_interrupted
from ._rheology import (
    Bingham,
    BinghamParams,
    Coussot,
    CoussotParams,
    HerschelBulkley,
    HerschelBulkleyParams,
    Internal,
    Law,
    Newtonian,
    NewtonianParams,
    Option,
    Param,
    law_of,
)
from ._rheology import parameters as material_parameters
from ._varied import basal_parameters, fit_parameters, parameter_value, replace_parameters, unused_parameters
from ._scene import Basal, Gate, Params, Scene, State, Wall, init_state, restate
from ._schema import SCHEMA, SceneError, builtin_scenes, load_scene, register_law, unregister_law, validate
from ._simulate import Frame, Pacer, chunkable, make_advance, make_chunk, make_steps, run, run_chunked, simulate
from ._step import make_step
from ._transfer import flat_transfers, make_p2g
from ._version import __version__ as __version__  # re-exported

__all__ = [
    "SCHEMA",
    "STEPS_WARN",
    "MemoryRefused",
    "check_memory",
    "estimate_run_time_s",
    "SceneError",
    "validate",
    "Setup",
    "build",
    "builtin_scenes",
    "load_scene",
    "make_params",
    "time_step_limits",
    "register_law",
    "unregister_law",
    "Law",
    "Param",
    "Option",
    "Internal",
    "law_of",
    "material_parameters",
    "fit_parameters",
    "basal_parameters",
    "replace_parameters",
    "unused_parameters",
    "parameter_value",
    "runout",
    "free_surface_front",
    "FRONT_FRACTION",
    "height_profile",
    "smooth_front",
    "deposited_volume",
    "particle_volume",
    "gaussian_kernel",
    "kinetic_energy",
    "time_to_rest",
    "atomic_write_text",
    "config_hash",
    "check_interrupted",
    "Bingham",
    "BinghamParams",
    "Coussot",
    "CoussotParams",
    "HerschelBulkley",
    "HerschelBulkleyParams",
    "Newtonian",
    "NewtonianParams",
    "Gate",
    "Params",
    "Basal",
    "Scene",
    "State",
    "Wall",
    "init_state",
    "restate",
    "Frame",
    "make_advance",
    "make_chunk",
    "make_steps",
    "chunkable",
    "Pacer",
    "run_chunked",
    "run",
    "simulate",
    "make_p2g",
    "flat_transfers",
    "make_step",
    "tait_pressure",
    "plotting",
    "run_scene",
    "RunFailure",
    "Interrupted",
]
