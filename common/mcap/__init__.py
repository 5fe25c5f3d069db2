"""Zenoh streams in MCAP files (https://mcap.dev): record, export, replay.

``log`` writes streams as they arrive and reads them back (also after a kill); ``process``
runs that writer in a process of its own; ``export`` turns a run folder into MCAP;
``replay`` publishes a recording back onto Zenoh with its timing.

Who may import it: any package (it is on the ground floor); it imports only ``common`` and
the ``mcap`` library.
"""
