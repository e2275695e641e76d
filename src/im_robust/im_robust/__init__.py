"""Robust static output-feedback synthesis for polytopic linear systems (seed 001), ROS-free."""
