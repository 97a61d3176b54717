"""A PX4-like mock vehicle (quadrotor and rover) speaking MAVLink; independent of companion."""
