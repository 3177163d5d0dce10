"""Registers the ``scpi-supply``, ``command`` and ``usb-hub`` power controls."""

from __future__ import annotations

from magline.plugin import hookimpl


@hookimpl
def magline_register_power_controls(register):
    from magline.plugins.power.command import CommandOptions, create_command_power
    from magline.plugins.power.scpi_supply import ScpiSupplyOptions, create_scpi_supply
    from magline.plugins.power.usb_hub import UsbHubOptions, create_usb_hub_power

    register("scpi-supply", create_scpi_supply, options=ScpiSupplyOptions)
    register("command", create_command_power, options=CommandOptions)
    register("usb-hub", create_usb_hub_power, options=UsbHubOptions)
