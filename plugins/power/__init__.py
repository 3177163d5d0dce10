"""Fixture power control for the persistence check: ``scpi-supply`` (a programmable bench supply over
SCPI) and ``command`` (external programs, e.g. USB hub switching).  ``link-reboot``, the
default, lives in the core (``core/power.py``)."""
