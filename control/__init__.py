"""Control: drive-by-wire logic, Ackermann conversions, path tracking."""
