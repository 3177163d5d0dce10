"""The INAV DUT backend, over MSP: INAV stores a per-axis calibration (``magzero_*`` offsets in the
sensor's raw counts, ``maggain_*`` gains, 1024 = unity) and streams its compass only calibrated and
aligned, so the station writes a neutral calibration before the tumble and turns the readings back into
the sensor's axes.  Written against :mod:`magline.plugin` alone, as the proof that a firmware with
another protocol fits the kit (``docs/writing-a-backend.md`` walks through it).  Modules: ``options``,
``calibration`` (counts, gains, alignment: the firmware's conventions), ``link`` (settings, status and
readings over MSP), ``dut`` (the backend), ``plugin``."""
