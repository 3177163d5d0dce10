"""The compasses' current interference (issue 46): the field the unit's own power wiring adds at each
compass, measured per amp by a current sweep with the unit still, judged, and written as the
firmware's current compensation where the product asks.

- :mod:`.source`: what draws the current (the plugin contract; ``plugins/current``);
- :mod:`.sweep`: the sweep itself, 0 → ``current_max_a`` → 0;
- :mod:`.hold`: how long a compensated unit's sweep holds its ends, to know each slope to a share of itself;
- :mod:`.line`: the straight line through a sweep's readings, with its σ;
- :mod:`.model`: each compass's field per amp, σ, linearity and return to zero;
- :mod:`.checks`: the measurements a unit is judged on;
- :mod:`.phase`: how the sequencer runs it, writes it and proves it after the power cycle.
"""
