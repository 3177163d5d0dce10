"""Registers the ``inav`` DUT backend."""

from __future__ import annotations

from typing import TYPE_CHECKING

from magline.plugin import hookimpl

if TYPE_CHECKING:
    from magline.plugin import Product
    from magline.plugins.inav.dut import InavDut
    from magline.plugins.inav.options import InavOptions


def create_inav_dut(product: Product, options: InavOptions) -> InavDut:
    from magline.plugins.inav.dut import InavDut

    return InavDut(product, options)


@hookimpl
def magline_register_dut_backends(register):
    register("inav", create_inav_dut, options="magline.plugins.inav.options:InavOptions", stores={
        "parameters": "magzero/maggain/align_mag in INAV's EEPROM settings; INAV has no factory calibration store"})


@hookimpl
def magline_connection_problem(backend, connection):
    if backend != "inav":
        return None
    from magline.plugin import ConnectionForms, connection_problem

    # what the MSP client opens (magline.core.links.msp): a TCP socket or a serial port
    return connection_problem(connection, ConnectionForms(("tcp",), url=False,
                                                          expected="tcp:HOST:PORT or serial:DEVICE[:BAUD]"))
