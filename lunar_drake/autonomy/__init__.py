"""Rover and operations software cores (pure Python/numpy, no Drake): the command
vocabulary, the on-board command executor, wheel odometry and telemetry packing."""
