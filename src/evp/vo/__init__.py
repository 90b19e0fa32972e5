"""Light visual odometry without a persistent map."""
