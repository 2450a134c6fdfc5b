"""Control laws (pure): gimbal PI(D) on angular error, guidance setpoints, target geolocation."""
