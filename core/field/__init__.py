"""Field sources: the expected local field the calibrated sphere must match."""
