"""Reports and plots of the estimators (Table 3, EKF, realism); no numerics of their own."""
