"""
Shared motor model, parameters, frames, topics, message conversions, lock-step helper.

ROS-free math plus thin ROS helpers.
"""
