"""The mock DUT: an in-process simulated flight controller for the demo station and the tests.

It has a magnetometer with known hard and soft iron, a simulated operator (first attempt spins
the unit about one axis only, later attempts tumble it), and non-volatile storage in a real file,
so the power-cycle check in the verify phase is real: a reboot reloads only what was committed.
"""
