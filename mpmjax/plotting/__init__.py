"""Plots of a finished (or interrupted) run read back from ``result.h5``.

Every function takes ``result``: the dict returned by ``mpmjax._io.read_result``, or a path
to a ``result.h5`` file (or to the run folder holding it).  Matplotlib only; nothing here
needs a display (it works with the Agg backend, which matplotlib picks by itself on a
headless machine).  Functions that draw return the matplotlib Axes; pass ``ax=`` to draw
into a figure of your own.

* ``particles(result, frame, field)``: side view (3D: side or plan view) of one frame,
  coloured by a stored field, with a colour bar in the field's unit.
* ``profiles(result, times, data)``: free-surface or kernel height profiles at chosen times,
  with measured profiles (``calibration.data.Profile`` or ``(x_m, h_m)`` arrays) overlaid.
* ``runout_vs_time(result)``: the front position (``mpmjax.runout``) against time.
* ``animate(result, path, field)``: a GIF of the particles, one image per saved frame.
* 3D runs: ``plan_map(maps, frame, quantity)``: a binned plan-view map from ``plan_view.h5``
  (bin-mean log10 viscosity, speed, thickness); ``section(result, frame, field, along=)``:
  a side (x-z) or transverse (y-z) section; ``plot_3d_overview``: the ``plan_view.png`` and
  ``sections.png`` that ``mpmjax run`` writes.
* ``plot_result(path_png, result, summary, title)``: the ``result.png`` that ``mpmjax run``
  writes, a one-page report (``result_figure``): viscosity side views at ~1 s, ~5 s and the
  end on a robust log scale (``viscosity_norm``), λ for Coussot runs, thickness profiles at up
  to 6 times (``result_profiles``), runout against time with its final value and the wall.

Fields (``FIELDS``): ``mu`` effective viscosity [Pa·s] (log colour scale), ``lambda``
Coussot structure parameter [-], ``speed`` |v| [m/s], ``vx`` and the vertical velocity
``vz`` [m/s], ``J`` volume ratio [-], ``displacement`` |x - x(t=0)| [m].  ``lambda`` exists
only for Coussot scenes; the error for an unknown or missing field lists the allowed ones.

One private module a concept, re-exported here: ``_data`` (reading a result: fields, frames,
profiles, runout), ``_views`` (particles, profiles, runout against time), ``_animation``,
``_plan`` (3D plan views and sections), ``_report`` (``result.png``) and ``_hazard_maps``
(``hazard_maps.png``).
"""

from ._animation import animate
from ._data import FIELDS, field_values, load, profile_at, runout
from ._hazard_maps import plot_hazard_maps
from ._plan import PLAN_QUANTITIES, load_plan_view, plan_map, plot_3d_overview, section
from ._report import plot_result, result_figure, result_profiles, viscosity_norm
from ._views import particles, profiles, runout_vs_time

__all__ = [
    "FIELDS",
    "PLAN_QUANTITIES",
    "animate",
    "field_values",
    "load",
    "load_plan_view",
    "particles",
    "plan_map",
    "plot_3d_overview",
    "plot_hazard_maps",
    "plot_result",
    "profile_at",
    "result_figure",
    "result_profiles",
    "profiles",
    "runout",
    "runout_vs_time",
    "section",
    "viscosity_norm",
]
