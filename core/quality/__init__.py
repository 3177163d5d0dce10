"""Process quality: the in-run review against the process's own spread, control charts and their
rules, capability, yield — everything that judges the line rather than one unit."""
