"""Ground-plane person tracking with an unscented Kalman filter."""
