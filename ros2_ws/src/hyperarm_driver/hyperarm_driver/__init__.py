"""hyperarm_driver: Dynamixel, PMAC rail and mock drivers, and wire-protocol emulators."""
