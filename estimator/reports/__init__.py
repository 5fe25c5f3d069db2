"""Reports and plots of the estimators (Table 3, EKF, realism); no numerics of their own.
Also the use cases of the commands that report an estimate, each a function a notebook
calls and a report object (its JSON, text lines and files): ``batch_report``
(``estimate batch``), ``bound_report`` (``estimate crlb``), ``montecarlo_report``
(``estimate montecarlo``), ``design_report`` (``design``), ``segments_report``
(``estimate batch --segments``, ``--thruster-health``), their text in ``estimate_text``."""
