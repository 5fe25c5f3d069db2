"""Raw datagram captures (pcap, pcapng) of a motion-capture stream.

``formats`` holds the formats' numbers and unwraps one captured packet to its UDP datagram;
``reader`` reads classic pcap and pcapng; ``writer`` writes the classic pcap files the bridge
records.

Who may import it: the rest of ``mocap_bridge`` and the floors above it (``calibration``,
``estimator``, ``tpods``); never ``common`` or ``bench``.
"""
