"""What the operator sees, in one place: the terminal console, the slot board of a station with
slots, and the station screen (a web page).  They are listeners: each is a plugin of the hooks in
:mod:`magline.core.hookspecs` and none of them decides anything about a unit."""
