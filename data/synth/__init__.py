"""Procedural orchard and vineyard worlds in pybullet, rendered to RGB, depth and exact masks."""
