"""The EKF family: the general filter, its filterpy adapter and the vectorised Monte Carlo filter.

``ekf`` is the one import of the filter (every public name is importable from it); behind it
``config`` (state layout, settings, presets), ``kernels`` (one step on plain arrays),
``loop`` (the filter over a pose history), ``methods`` (``ekf`` and ``ls-ekf`` on a whole
run), ``result`` (what a run returns), ``plausibility`` (what a run says about itself),
``ext`` (the extended-state filter), ``vec`` (many runs at once) and ``filterpy_adapter``.

Who may import it: ``estimator.live``, ``estimator.montecarlo``, ``estimator.estimate``,
``estimator.reports`` and ``tpods``; not ``estimator.plant`` or ``estimator.batch``.
"""
