"""Registers the ``mock`` DUT backend: an in-process unit (the simulators on real sockets are ``magline.sim``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from magline.plugin import hookimpl

if TYPE_CHECKING:
    from magline.plugin import Product
    from magline.plugins.mock.dut import MockDut
    from magline.plugins.mock.options import MockOptions


def create_mock_dut(product: Product, options: MockOptions) -> MockDut:
    # imported when a unit is tested, not when the plugin loads: the simulated sensor's scipy
    # rotations would cost every command (spc, report, history) a third of a second
    from magline.plugins.mock.dut import MockDut

    return MockDut(options)


@hookimpl
def magline_register_dut_backends(register):
    register("mock", create_mock_dut, options="magline.plugins.mock.options:MockOptions")

