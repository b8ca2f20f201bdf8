"""Reproduction and performance studies: ``mpmjax bench``, ``stress``, ``records``, ``pareto`` and
``study`` (modules ``bench``, ``stress``, ``records``, ``pareto``, ``tables``).

They use the library (``mpmjax.run_scene``, ``build``, ``simulate``, ...); nothing in the library
imports them (only the command line, ``mpmjax.cli``, does).
"""
