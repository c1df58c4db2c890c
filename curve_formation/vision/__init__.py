"""Overhead camera: ArUco markers, arena calibration, rendering (OpenCV, no ROS)."""
