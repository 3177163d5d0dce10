"""Drivers that turn a firmware's own SITL build through a motion and a distortion whose truth is known.

magline's simulators (``magline.sim``) reproduce what each firmware does as far as it was read and seen;
these drivers feed the real firmware instead, so that a station run against it can be held to a truth:
INAV through its X-Plane-protocol peer (:mod:`magline.sitl.inav_xplane`), PX4 through ``HIL_SENSOR``
(:mod:`magline.sitl.px4_hil`, its power cut by :mod:`magline.sitl.px4_power`), ArduCopter through its own
simulator's parameters (:mod:`magline.sitl.ardupilot_run`); each ``*_run`` module runs the real station on
one firmware and prints what it kept against the truth.  Nothing here builds a
firmware: a SITL binary is the user's, built from the firmware's own instructions.
"""
