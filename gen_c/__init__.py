"""Generated, freestanding C setpoint library and its loader."""
