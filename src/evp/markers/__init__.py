"""Seed 003's marker tracking and marker map: detection (OpenCV ArUco), per-marker 6-DoF pose,
the paper's adjacency map and grid, and a metric map refined by a small pose graph."""
