"""Optimisation shared by geometry, SLAM and visual odometry: bundle adjustment, the reprojection
error and its chi-square gates. It imports nothing from evp.geometry or evp.slam, which both use it."""
