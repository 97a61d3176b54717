"""The onboard PX4 module's side of the companion: the trajectory upload protocol
(`protocol`, sans I/O) to gen_c/px4_module/ecca_onboard.c."""
