"""Registers the ``px4`` DUT backend."""

from __future__ import annotations

from typing import TYPE_CHECKING

from magline.plugin import hookimpl

if TYPE_CHECKING:
    from magline.plugin import Product
    from magline.plugins.px4.dut import Px4Dut
    from magline.plugins.px4.options import Px4Options


def create_px4_dut(product: Product, options: Px4Options) -> Px4Dut:
    from magline.plugins.px4.dut import Px4Dut  # on use: its MAVLink library would slow every command's start

    return Px4Dut(product, options)


@hookimpl
def magline_register_dut_backends(register):
    register("px4", create_px4_dut, options="magline.plugins.px4.options:Px4Options", stores={
        "parameters": "CAL_MAGn_* in the parameter file, which a reset to defaults erases",
        "factory-storage": "PX4's factory calibration store (/fs/mtd_caldata), written by the commander's gyro "
                           "calibration with SYS_FAC_CAL_MODE = 1 and loaded at boot under the user's parameters"})


# what MAVSDK opens (its own parser: scheme://HOST:PORT, a port from 1; the legacy udp:// and tcp:// too)
CONNECTION_FORMS = "udpin://HOST:PORT, udpout://HOST:PORT, tcpout://HOST:PORT, tcpin://HOST:PORT or serial:DEVICE:BAUD"


@hookimpl
def magline_connection_problem(backend, connection):
    if backend != "px4":
        return None
    from magline.plugin import ConnectionForms, connection_problem

    return connection_problem(connection, ConnectionForms(("udpin", "udpout", "tcpout", "tcpin", "udp", "tcp"),
                                                          url=True, expected=CONNECTION_FORMS, hostless=("udp",)))
