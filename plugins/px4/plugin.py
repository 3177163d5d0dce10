"""Registers the ``px4`` DUT backend."""

from __future__ import annotations

from magline.core.dut import validated_options
from magline.core.plugins import hookimpl
from magline.core.station.schema import Product
from magline.plugins.px4.dut import Px4Dut
from magline.plugins.px4.options import Px4Options


def create_px4_dut(product: Product) -> Px4Dut:
    return Px4Dut(product, validated_options(Px4Options, product.options, "px4 backend"))


@hookimpl
def magline_register_dut_backends(register):
    register("px4", create_px4_dut, options=Px4Options)
