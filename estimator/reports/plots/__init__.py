"""The figures of the estimators' reports (matplotlib, Agg backend, PNG files).

``batch`` (a batch fit's residuals and trajectory), ``ekf`` (a filter run's estimates,
sigmas and NIS), ``segments`` (a fit by segments), ``structure`` (a structure's outline and
thrusters) and ``realism`` (the realism report's residuals, autocorrelation and Monte Carlo).

Who may import it: the rest of ``estimator.reports`` and ``tpods``; it imports matplotlib,
so a caller that only wants numbers imports it inside the function that draws.
"""
