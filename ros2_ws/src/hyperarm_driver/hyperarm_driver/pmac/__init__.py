"""Delta Tau Turbo PMAC support (no ROS): Ethernet protocol, client, rail axis, emulator.

- :mod:`.protocol`: the Turbo PMAC Ethernet packet format and reply parsing.
- :mod:`.client`: blocking TCP (and optional serial) client with timeouts and reconnection.
- :mod:`.axis`: one PMAC motor as the hyperarm rail (metres, soft limits, status decode).
- :mod:`.driver`: a polling worker thread around the axis (link supervision, torque rule,
  fault latch), used by the node.
- :mod:`.watchdog`: the on-card safety PLC (host watchdog, fault latch) downloaded at configure.
- :mod:`.plc`: the subset of the PMAC command/PLC language the emulator interprets.
- :mod:`.emulator`: a loopback TCP emulator of the card for tests and demos.
"""
