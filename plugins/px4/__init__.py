"""The PX4 DUT backend (MAVSDK 4.x, raw MAVLink through its MavlinkDirect plugin): writes
CAL_MAGn_* of the slot whose CAL_MAGn_ID is the calibrated sensor, forces the parameter save,
reboots and proves the calibration survived with a fresh link.  Modules: ``link`` (MAVSDK),
``calibration`` (units, signs, slot choice), ``dut`` (the backend), ``plugin``."""
