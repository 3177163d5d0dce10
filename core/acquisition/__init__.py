"""The acquire phase's rules: when a tumble is determined, stalled or too short (``tumble_stop``)."""
