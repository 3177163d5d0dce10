"""The Helmholtz coil field source: applies known field vectors to a unit standing still, so the
fit solves the full affine model (offset and a full 3×3 matrix with the sensor's misalignment).
Modules: ``options``, ``coil`` (the SCPI current source), ``source`` (shift checks, schedule),
``plugin`` (field-source registration, coil acquisition and affine fit hooks)."""
