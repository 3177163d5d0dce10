"""The ArduPilot DUT backend (pymavlink): writes COMPASS_OFS/DIA/ODI/SCALE of the compass set whose
DEV_ID is the calibrated sensor, force-saves the device ids, reboots and proves the calibration
survived (read-back plus ArduPilot's own arming check).  Modules: ``link`` (MAVLink protocol),
``calibration`` (units, signs, limits, inverse correction), ``dut`` (the backend), ``plugin``."""
