"""Registers the ``scpi-supply``, ``command`` and ``usb-hub`` power controls."""

from __future__ import annotations

from magline.plugin import hookimpl


@hookimpl
def magline_register_power_controls(register):
    # named by place: each control's module is imported when a station file uses it
    register("scpi-supply", "magline.plugins.power.scpi_supply:create_scpi_supply",
             options="magline.plugins.power.scpi_supply:ScpiSupplyOptions")
    register("command", "magline.plugins.power.command:create_command_power",
             options="magline.plugins.power.command:CommandOptions")
    register("usb-hub", "magline.plugins.power.usb_hub:create_usb_hub_power",
             options="magline.plugins.power.usb_hub:UsbHubOptions")
