"""Seed 001's EKF-SLAM for a wheeled robot carrying a phone: the robot's planar pose, the gyro's
bias, the camera's position on the robot and inverse-depth features (Civera, Davison and
Montiel 2008) in one extended Kalman filter, predicted by the wheels and the gyro and updated by
the features' bearings in the image."""
