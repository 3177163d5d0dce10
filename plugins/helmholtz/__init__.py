"""The helmholtz plugin — not implemented yet (see its issue); registers no entry point until it works."""
