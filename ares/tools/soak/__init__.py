"""`ares soak`: a fault-injection soak of the whole stack (plan, injectors, measurements, report)."""
