"""The ACME line protocol: ASCII commands and replies, one per line, over TCP.

    ID?            -> ID <model> <firmware> <device id>
    STREAM <hz>    -> M <t_ms> <x_mG> <y_mG> <z_mG> <ax_mg> <ay_mg> <az_mg>
                      (one line per reading, until STOP; the accelerometer in milli-g, body axes)
    STOP           -> OK STOP
    GET <name>     -> VAL <name> <value>             (ERR <why> for an unknown name)
    SET <name> <v> -> VAL <name> <value as stored, float32>
    SAVE           -> OK SAVE                          (RAM parameters to flash)
    REBOOT         -> OK REBOOT, then the link closes; the board boots from flash
    UPTIME?        -> UPTIME <seconds>
    CAL?           -> C <x_mG> <y_mG> <z_mG>           (one reading with the calibration applied)
    TEMP?          -> TEMP <celsius>                  (the board's own temperature sensor)

Calibration as the firmware applies it: ``cal = S · (raw + OFS)``, OFS in milligauss (added),
S the symmetric matrix ``S_XX … S_YZ``.  ``AUTOCAL`` (1: the firmware learns offsets by itself).
"""

PARAMS: dict[str, float] = {"OFS_X": 0.0, "OFS_Y": 0.0, "OFS_Z": 0.0, "S_XX": 1.0, "S_YY": 1.0, "S_ZZ": 1.0,
                            "S_XY": 0.0, "S_XZ": 0.0, "S_YZ": 0.0, "AUTOCAL": 1.0}
MATRIX = (("S_XX", 0, 0), ("S_YY", 1, 1), ("S_ZZ", 2, 2), ("S_XY", 0, 1), ("S_XZ", 0, 2), ("S_YZ", 1, 2))
UT_PER_MG = 0.1
