"""Navigation core: earth model, rotations, strapdown mechanization, error-state Kalman filter (numpy/scipy only)."""
