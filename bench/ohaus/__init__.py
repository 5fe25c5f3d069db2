"""The OHAUS Scout balance over serial: the driver and what it reads.

``driver`` holds :class:`driver.OhausScout` (commands, replies, stability); ``acquisition``
reads continuously (continuous print, ``IP`` polling or both); ``lines`` parses one printed
line (pure, no I/O); ``replies`` sorts what a balance sends and names the errors.

Who may import it: the rest of ``bench`` and the floors above it (``calibration``,
``estimator``, ``tpods``); never ``common`` or ``mocap_bridge``.
"""
