"""Perception: GNSS/NMEA and UTM, wheel odometry, UKF fusion, LiDAR filters, ground removal,
occupancy grid, road-boundary detection."""
