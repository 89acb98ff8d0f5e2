"""Dynamixel Protocol 2.0 bus: model table, protocol codec, emulator, SDK-based bus (no ROS)."""
