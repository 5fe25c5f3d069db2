"""The EKF family: the general filter, its filterpy adapter and the vectorised Monte Carlo filter."""
