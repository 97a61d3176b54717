"""ecca-offboard companion: planning, flatness setpoints and the PX4 offboard link."""
