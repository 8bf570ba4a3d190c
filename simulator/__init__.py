"""The simulated vehicle: raw actuators (actuators), the road under the wheels (road), vehicle
physics (vehicle) and sensor models (sensors)."""
