"""Device drivers: each reads one kind of device's wire format and publishes the topics the
simulator publishes in simulation (GNSS NMEA, Velodyne UDP packets, CAN frames by a DBC)."""
