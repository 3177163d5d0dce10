"""What a backend or an instrument plugin uses to talk to hardware: readings out of a MAVLink stream
(repeats dropped, int16 truncation undone), waits that do not take the station's own stalls for a
silent vehicle, SCPI sessions, and the MAVLink tap that records a link's traffic."""
