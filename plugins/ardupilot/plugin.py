"""Registers the ``ardupilot`` DUT backend."""

from __future__ import annotations

from typing import TYPE_CHECKING

from magline.plugin import hookimpl

if TYPE_CHECKING:
    from magline.plugin import Product
    from magline.plugins.ardupilot.dut import ArduPilotDut
    from magline.plugins.ardupilot.options import ArduPilotOptions


def create_ardupilot_dut(product: Product, options: ArduPilotOptions) -> ArduPilotDut:
    from magline.plugins.ardupilot.dut import (
        ArduPilotDut,  # on use: its MAVLink library would slow every command's start
    )

    return ArduPilotDut(product, options)


@hookimpl
def magline_register_dut_backends(register):
    register("ardupilot", create_ardupilot_dut, options="magline.plugins.ardupilot.options:ArduPilotOptions", stores={
        "parameters": "COMPASS_OFS/DIA/ODI/MOT in the parameter storage; ArduPilot's persistent parameters in "
                      "the bootloader sector hold IMU temperature calibration, accelerometer ids and OpenDroneID "
                      "only (AP_HAL_ChibiOS/Util.cpp), no factory store for the compass"})


@hookimpl
def magline_connection_problem(backend, connection):
    if backend != "ardupilot":
        return None
    from magline.plugin import ConnectionForms, connection_problem

    # what pymavlink opens: scheme:HOST:PORT
    return connection_problem(connection, ConnectionForms(("tcp", "udpin", "udpout", "udp"), url=False, expected=(
        "tcp:HOST:PORT, udpin:HOST:PORT, udpout:HOST:PORT or serial:DEVICE:BAUD")))
