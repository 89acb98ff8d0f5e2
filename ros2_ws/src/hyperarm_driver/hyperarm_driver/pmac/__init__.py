"""Delta Tau Turbo PMAC support (no ROS): Ethernet protocol, client, rail axis, emulator.

- :mod:`.protocol`: the Turbo PMAC Ethernet packet format and reply parsing.
- :mod:`.client`: blocking TCP (and optional serial) client with timeouts and reconnection.
- :mod:`.axis`: one PMAC motor as the hyperarm rail (metres, soft limits, status decode).
- :mod:`.driver`: a polling worker thread around the axis (link supervision), used by the node.
- :mod:`.emulator`: a loopback TCP emulator of the card for tests and demos.
"""
