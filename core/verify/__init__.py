"""The verify phase's room: what proves, after the power cycle, that the calibration the unit holds is
the one magline fitted and that the unit applies it."""
