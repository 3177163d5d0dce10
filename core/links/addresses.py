"""What a product's ``connection`` may be, checked when a station file is read: a serial port, or a host and a
port behind one of the schemes the backend's link library opens.

Why: a connection no link can open — a port past 65535, a scheme the library does not know — was found only
when a unit was connected, as an ERROR of every unit that no retest could cure; ``magline check`` names it
with its line instead.  Whether a unit answers there is still the connect phase's to find.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from magline.core.links.serial_port import SerialAddress, SerialAddressError

# a connection that reaches one vehicle (a network or serial link): one unit's run at a time, one slot per link
VEHICLE_LINK = re.compile(r"^(tcp|tcpin|tcpout|udp|udpin|udpout|serial|com|/dev/)", re.IGNORECASE)


def names_a_vehicle_link(connection: str) -> bool:
    """Whether ``connection`` reaches a vehicle of its own (an in-process mock's does not)."""
    return bool(VEHICLE_LINK.match(connection.strip()))


@dataclass(frozen=True)
class ConnectionForms:
    """The connections a backend's link takes: ``SCHEME://HOST:PORT`` (``url``, MAVSDK's) or
    ``SCHEME:HOST:PORT`` (pymavlink's, MSP's) for each of ``schemes``, and a serial port."""

    schemes: tuple[str, ...]
    url: bool
    expected: str  # the forms in the engineer's words, for the message
    hostless: tuple[str, ...] = ()  # schemes whose HOST may be left out (MAVSDK's udp://:PORT listens on all)


def connection_problem(connection: str, forms: ConnectionForms) -> str | None:
    """What is wrong with ``connection`` for a backend taking ``forms``; None when it is well formed."""
    try:
        if SerialAddress.parse(connection) is not None:
            return None
    except SerialAddressError as exc:
        return str(exc).removeprefix(f"connection {connection!r}: ")
    scheme, separator, rest = connection.partition("://" if forms.url else ":")
    if not separator or scheme not in forms.schemes or "/" in rest:  # tcp://… where tcp:… is taken
        return f"{connection!r} is no connection this backend opens: expected {forms.expected}"
    host, colon, port = rest.rpartition(":")
    if not colon or not (host or scheme in forms.hostless) or not port.lstrip("-").isdigit():
        return f"{connection!r} names no HOST:PORT: expected {forms.expected}"
    if not 1 <= int(port) <= 65535:
        return f"{port} is not a port (1 to 65535)"
    return None
