"""The turntable motion: a rotary stage under a two-axis cradle the operator tilts between its turns."""
