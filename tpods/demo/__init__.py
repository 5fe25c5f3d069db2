"""``tpods demo``: the lab day on emulated devices, no hardware needed.

``lab_day`` runs it (``register`` adds the subcommand); ``bench`` and ``stages`` are its
bench, flight and batch stages, ``fit`` the batch fit of the recorded run, ``procs`` the
processes and private Zenoh network of a flight, ``side`` the warm-up workers, ``fidelity``
how faithfully the emulated valves applied the commands, ``report`` and ``timing`` what it
writes at the end; ``structure`` (with ``structure_layout``, the truss, and
``structure_report``, its summary) and ``vehicle`` are the ``--structure`` and ``--vehicle``
days.

Who may import it: only :mod:`tpods.cli` (and the tests). Nothing below ``tpods`` does.
"""
