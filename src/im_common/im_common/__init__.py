"""
Shared motor model, parameters, frames, topics, message conversions and the lock-step helper (ROS-free math plus thin ROS helpers).
"""
