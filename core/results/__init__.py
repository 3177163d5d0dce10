"""Result sinks: where every unit's record is stored (SQLite by default)."""
