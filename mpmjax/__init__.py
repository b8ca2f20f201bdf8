"""mpmjax: a differentiable Material Point Method for thixotropic mine tailings, in JAX.

Public API (modules are private; names are re-exported here):

* scenes: ``load_scene``, ``validate`` (nested dict -> flat validated dict), ``build``,
  ``builtin_scenes``, ``SceneError``, ``SCHEMA``
* the step: ``make_step``, ``make_p2g``, ``Scene``, ``State``, ``Params``, ``init_state``
* time integration: ``simulate``, ``run``, ``make_advance``, ``Frame``
* rheology: ``Newtonian``, ``Bingham``, ``HerschelBulkley``, ``Coussot`` and their
  parameter NamedTuples
* observables: ``runout``
* runs on disk (what ``mpmjax run`` does): ``run_scene`` (result.h5, summary.json, plots,
  checkpoint and resume), ``RunFailure`` (a failed health check), ``Interrupted`` (SIGINT/SIGTERM)
* plots of a saved run: the ``plotting`` module (``particles``, ``profiles``,
  ``runout_vs_time``, ``animate``)
"""

from . import plotting  # imports matplotlib only when a plot is made
from ._config import SCHEMA, SceneError, Setup, build, builtin_scenes, load_scene, make_params, validate
from ._driver import Interrupted, run_scene
from ._health import RunFailure
from ._observables import runout
from ._rheology import (
    Bingham,
    BinghamParams,
    Coussot,
    CoussotParams,
    HerschelBulkley,
    HerschelBulkleyParams,
    Newtonian,
    NewtonianParams,
)
from ._scene import Gate, Params, Scene, State, Wall, init_state
from ._simulate import Frame, make_advance, make_chunk, run, simulate
from ._step import make_p2g, make_step, tait_pressure
from ._version import __version__ as __version__  # re-exported

__all__ = [
    "SCHEMA",
    "SceneError",
    "validate",
    "Setup",
    "build",
    "builtin_scenes",
    "load_scene",
    "make_params",
    "runout",
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
    "Scene",
    "State",
    "Wall",
    "init_state",
    "Frame",
    "make_advance",
    "make_chunk",
    "run",
    "simulate",
    "make_p2g",
    "make_step",
    "tait_pressure",
    "plotting",
    "run_scene",
    "RunFailure",
    "Interrupted",
]
