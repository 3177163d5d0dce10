"""The ``gimbal`` motion: a motorised two-axis gimbal turning the units of every slot at once."""
