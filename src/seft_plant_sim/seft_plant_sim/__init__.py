"""Simulated actuator + specimen rig for substructure EFT (ROS-free models + rig node)."""
