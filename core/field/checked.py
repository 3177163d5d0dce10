"""A field source's magnitude from a model or a survey, checked against an optional live reference (a
fluxgate, :mod:`magline.core.field.reference`).

Why apart from the reference: every command loads the field-source plugins that build on this class, and the
reference instrument's options model and arithmetic are needed only on a station that has one.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from magline.core.field.options import ReferenceOptions
    from magline.core.field.reference import ReferenceMonitor


class CheckedField:
    """A field magnitude from a model or a survey, checked against an optional live reference."""

    # The unit sits in this field after its power cycle too, so the verify phase can require the
    # firmware's calibrated output to read it (a coil's field is gone by then: it does not say this).
    reference_is_ambient = True

    def __init__(self, field_ut: float, reference: ReferenceOptions | None, model_name: str,
                 inclination_deg: float | None = None) -> None:
        self.field_ut = float(field_ut)
        self.inclination_deg = inclination_deg  # the field's dip (positive down), when the source knows it
        self.model_name = model_name
        self.monitor: ReferenceMonitor | None = None
        if reference is not None:
            from magline.core.field.reference import ReferenceMonitor

            self.monitor = ReferenceMonitor(reference, self.field_ut, model_name)

    def reference_field_ut(self) -> float:
        if self.monitor is not None:
            self.monitor.before_unit()
        return self.field_ut

    def finish_unit(self) -> None:
        return None

    def reference_inclination_deg(self) -> float | None:
        """The field's inclination at the station (degrees, positive down), or None when not known:
        the mounting check then measures the inclination the unit saw but cannot judge it."""
        return self.inclination_deg

    def describe(self) -> dict:
        """The reference as an operator screen shows it: the model value and the last fluxgate check."""
        out: dict = {"model": self.model_name, "field_ut": round(self.field_ut, 2)}
        if self.monitor is not None:
            out["last_check"] = self.monitor.last
        return out

    def close(self) -> None:
        if self.monitor is not None:
            self.monitor.close()
