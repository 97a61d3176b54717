"""Generated, freestanding C setpoint library and its tooling.

- ``gen_c/ecca_setpoint/``: the C library (generated CasADi code + hand-written API header).
- ``gen_c.generate`` / ``python -m gen_c``: the generator (imports ``companion.flatness``).
- ``gen_c.native``: build with the system compiler and call through ctypes (imports nothing
  from ``companion``, so the companion may use it for its hot path).
- ``gen_c.crossbuild``: Cortex-M7 cross-build with code size and stack measurement.
"""
