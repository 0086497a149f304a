"""Wheel odometry on the host: integration of the robot's counters into poses."""
