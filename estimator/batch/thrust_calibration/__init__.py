"""In-situ thrust calibration: thruster factors from a run of a body of known mass (and Izz).

``calibrate`` fits the factors of one module's thrust table (:func:`calibrate.calibrate_thrust`
and friends), ``fit`` holds the problem and its solver, ``result`` the result with its
uncertainty budget and the corrected table, ``izz`` the variant with only the mass known,
``vehicle`` the same for a body described by its thrusters. ``run`` is the use case on a
run folder (the table or vehicle file written), ``segments`` the same with the run fitted
by segments.

Who may import it: the rest of ``estimator.batch`` and the floors above it (``estimator.*``
other than ``plant``, and ``tpods``).
"""
