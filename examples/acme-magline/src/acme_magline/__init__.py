"""magline plugins for ACME line-protocol magnetometer boards (an example third-party distribution)."""
