"""``magline dashboard``: the line's page — every station live, the process, any unit — read-only over the
results store (SQLite for one station, PostgreSQL for a line)."""
