"""Managers: independent processes that each judge one aspect of the vehicle and publish a score
(odometry, path, mission, obstacle, speed, control, awareness)."""
