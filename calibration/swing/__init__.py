"""Izz from a hung body's swing: the bifilar pendulum, any swing trace, and the pendulum's check.

- ``bifilar``: Izz of a bifilar pendulum, the one import for the CLI; ``bifilar_eq19``: the
  paper's Equation 19 on stopwatch periods with its uncertainty; ``bifilar_model``: the
  large-angle model (equations, energy, simulation); ``bifilar_fit``: that model fitted to a
  recorded yaw trace.
- ``trace_fit``: Izz from any swing recording (angle, rate, or an angle-like signal), with
  ``signal_model`` (what a sensor records), ``lsq`` (the bounded fit and the second-mode
  search), ``trace_io`` (reading other labs' logs), ``units`` (a log in the wrong unit) and
  ``sim`` (simulated sensor traces).
- ``pendulum_check``: the test-mass check of an inertia pendulum, with ``pendulum_periods``
  (a period from any trace proportional to the angle), ``pendulum_plots`` and
  ``pendulum_series`` (the check of a SERIES.csv file, its files written).
- ``measure``: the use case, Izz from one source (timings, poses, rates or a trace) with
  its files written; ``summary``: its text report.

Who may import it: the rest of ``calibration`` and the floors above it (``estimator``,
``tpods``); never ``common``, ``bench`` or ``mocap_bridge``.
"""
