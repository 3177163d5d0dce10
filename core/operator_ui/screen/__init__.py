"""The station screen: the same sequencer and station file, driven from a browser on the line PC
(``magline station``).  ``state.py`` turns the listener hooks into what the page shows, ``runner.py``
runs one unit at a time off the web thread, ``app.py`` serves the page, its live events and its
two actions (start, abort)."""
