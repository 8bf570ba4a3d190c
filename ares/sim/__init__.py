"""The simulated vehicle: actuator and vehicle physics (plant) and sensor models (sensors)."""
