"""Built-in simulator: trajectories with exact truth and the IMU/GNSS data they imply."""
