"""The station-file schema.

Why pydantic: the schema is declared once, unknown keys and wrong types are rejected with the
exact key path, and the loader maps that path back to a line in the YAML file.  Strict mode: a
string is never silently turned into a number.
"""

from __future__ import annotations

import hashlib
import json
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    WrapValidator,
    field_validator,
    model_validator,
)

from magline.core.measurements import DEFAULT_LIMITS, KNOWN_LIMIT_NAMES, POSSIBLE, base_name, known_limit_name


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


class Location(_Strict):
    latitude_deg: Annotated[float, Field(ge=-90, le=90)]
    longitude_deg: Annotated[float, Field(ge=-180, le=180)]
    # height above mean sea level; bounded by where the World Magnetic Model holds (1 km below the ellipsoid
    # to 850 km above it), so a slip of sign or unit is a check error, not a field from outside the model
    altitude_m: Annotated[float, Field(ge=-1000, le=850_000)] = 0.0


class StationInfo(_Strict):
    id: str
    line: str
    location: Location
    # the line's shift starts, local clock times ("06:00,14:00,22:00"): the station screen counts the units
    # of the shift running now; unset, of the day
    shifts: str | None = None

    @field_validator("shifts")
    @classmethod
    def _clock_times(cls, text: str | None) -> str | None:
        from magline.core.quality.trends import Shifts

        Shifts.parse(text)  # ValueError naming the entry that is not a clock time
        return text


class Limit(_Strict):
    """A pass/fail rule for one measurement; ``marginal`` is a band inside the limit that flags review."""

    ge: float | None = None
    le: float | None = None
    range: Annotated[list[float], Field(min_length=2, max_length=2)] | None = None
    marginal: Annotated[float, Field(ge=0)] | None = None

    @model_validator(mode="after")
    def _one_rule(self) -> Limit:
        if self.range is not None and (self.ge is not None or self.le is not None):
            raise ValueError("give either range or ge/le, not both")
        if self.range is None and self.ge is None and self.le is None:
            raise ValueError("a limit needs ge, le or range")
        if self.range is not None and self.range[0] > self.range[1]:
            raise ValueError("range must be [low, high] with low <= high")
        if self.ge is not None and self.le is not None and self.ge > self.le:
            raise ValueError(f"empty acceptance window: no value is both ≥ {self.ge:g} and ≤ {self.le:g} "
                             "(every unit would fail)")
        return self

    @property
    def low(self) -> float | None:
        return self.range[0] if self.range is not None else self.ge

    @property
    def high(self) -> float | None:
        return self.range[1] if self.range is not None else self.le


def declared_measurements(info: ValidationInfo | None) -> dict[str, Any]:
    """The plugins' own measurements (name → ``DeclaredMeasurement``) the station file is read with: the
    validation context's ``measurements`` (:func:`~magline.core.station.load_station_text` passes the
    loaded plugins' declarations), none when read without plugins."""
    context = info.context if info is not None and isinstance(info.context, dict) else {}
    return context.get("measurements") or {}


def _known_measurement(name: str, info: ValidationInfo) -> str:
    declared = declared_measurements(info)
    if not known_limit_name(name) and base_name(name) not in declared:
        import difflib

        known = sorted(KNOWN_LIMIT_NAMES | set(declared))
        close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ValueError(f"unknown measurement {name!r}{hint}; known: {', '.join(known)} "
                         "(a sensor's own: mag2.<name>; a pair's: mag1-mag2.<name>; a plugin's own measurement "
                         "is known once its plugin declares it with the magline_register_measurements hook)")
    return name


def _possible_windows(limits: Any, handler: Any, info: ValidationInfo) -> dict[str, Limit]:
    """A window no value of the measurement can reach (``coverage: {ge: 1.5}``) fails every unit: said at
    the limit's own line, together with whatever else is wrong in the same limit set (one pass)."""
    impossible = []
    for name, rule in (limits or {}).items() if isinstance(limits, dict) else ():
        if not isinstance(rule, dict):
            continue
        low = rule.get("ge", (rule.get("range") or [None, None])[0])
        high = rule.get("le", (rule.get("range") or [None, None])[1])
        declared = declared_measurements(info).get(base_name(str(name)))
        lowest, highest = POSSIBLE.get(base_name(str(name)), declared.possible if declared is not None
                                       else (float("-inf"), float("inf")))
        numbers = all(v is None or isinstance(v, int | float) for v in (low, high))
        empty = numbers and low is not None and high is not None and low > high  # the Limit itself says so
        if numbers and not empty and ((low is not None and low > highest) or (high is not None and high < lowest)):
            impossible.append((name, f"no value can lie in [{_bound(low)}, {_bound(high)}]: {base_name(str(name))} is "
                                     f"always within [{_bound(lowest)}, {_bound(highest)}] (every unit would fail)"))
    errors = [{"type": "value_error", "loc": (name,), "input": limits[name], "ctx": {"error": ValueError(text)}}
              for name, text in impossible]
    try:
        result = handler(limits)
    except ValidationError as exc:
        if not errors:
            raise
        errors += [{"type": e["type"], "loc": e["loc"], "input": e["input"],
                    **({"ctx": e["ctx"]} if "ctx" in e else {})} for e in exc.errors()]
        raise ValidationError.from_exception_data(exc.title, errors) from None
    if errors:
        raise ValidationError.from_exception_data("limits", errors)
    return result


def _bound(value: float | None) -> str:
    return "—" if value is None or abs(value) == float("inf") else f"{value:g}"


LimitSet = Annotated[dict[Annotated[str, AfterValidator(_known_measurement)], Limit], WrapValidator(_possible_windows)]


class PowerConfig(_Strict):
    """How the verify phase cycles power: ``link-reboot`` (default: the backend's own reboot command), ``scpi-supply``,
    ``command``, ``usb-hub``."""

    method: str = "link-reboot"
    options: dict[str, Any] = Field(default_factory=dict)


class CurrentSourceConfig(_Strict):
    """What draws the current for the interference sweep: ``electronic-load`` (SCPI, in the unit's
    power path downstream of its current sensor) or ``motor-test`` (the unit's own motors, props off)."""

    type: str
    options: dict[str, Any] = Field(default_factory=dict)


class InterferenceSettings(_Strict):
    """How the current sweep is run: ``steps`` levels from 0 up to the product's ``current_max_a`` and as
    many back down to 0 (the return to zero is judged), each held ``settle_s`` before ``readings``
    readings of every compass are taken; the stream asks for ``rate_hz`` — unset, for 100 Hz, or the fastest
    a serial line carries (a stream faster than a compass only repeats its readings, which are dropped,
    and one slower than it throws readings away that a compensated unit's hold would need).  The defaults (0, ½, 1, ½, 0
    of the top, 8 readings) take about 6 s at ArduPilot's 10 Hz compasses.  The proof after the power
    cycle needs only the slope: 0, 1, 0.

    Why ``target_sigma_ut_per_a``: the field per amp is only as good as the compasses' noise over the
    current swept — 8 readings a step hold it to 2 % + 0.01 µT/A at 0.3 µT of noise and 40 A, not at
    1 µT or 10 A.  So the first (0 A) step measures each compass's noise, and every step then reads as
    many readings as bring the slope's 1σ per axis to the target (``readings`` the least,
    ``readings_max`` the most: a noisier compass is given more time, never an imprecise figure
    silently)."""

    steps: Annotated[int, Field(ge=2, le=20)] = 2
    settle_s: Annotated[float, Field(ge=0.0, le=30.0)] = 0.3
    readings: Annotated[int, Field(ge=3, le=1000)] = 8
    target_sigma_ut_per_a: Annotated[float, Field(gt=0)] = 0.005
    readings_max: Annotated[int, Field(ge=3, le=5000)] = 200
    rate_hz: Annotated[float, Field(gt=0, le=400)] | None = None
    timeout_s: Annotated[float, Field(gt=0)] = 60.0  # the whole sweep
    # a compensated unit: its top and last zero steps are held until every compass's written slope is known to
    # this share of itself (3σ) — about what compensation may leave of its interference —, as far as
    # ``compensation_budget_s`` (its sweep and the proof after the power cycle together) allows.  The hold is
    # planned from the sweep's own step costs, and the two sweeps ended up to 0.3 s past the plan on the
    # simulators (0.45 s with each step costed at the mean step; the proof's steps cost a little more than the
    # sweep's): 9.5 s leaves the 10 s a unit may spend on its interference room for it
    compensation_goal_pct: Annotated[float, Field(gt=0, le=100)] = 5.0
    compensation_budget_s: Annotated[float, Field(gt=0)] = 9.5

    @model_validator(mode="after")
    def _most_at_least_least(self) -> InterferenceSettings:
        if self.readings_max < self.readings:
            raise ValueError(f"readings_max ({self.readings_max}) is below readings ({self.readings}): the most "
                             "readings a step may take cannot be fewer than the least")
        return self


class TimeSkew(_Strict):
    """A product's magnetometer time skew as measured (``time_skew: {ms: -31, sigma_ms: 4}``): how much
    later than its message's stamp a reading is taken, and how far one unit's may be off it."""

    ms: Annotated[float, Field(ge=-150, le=150)]
    sigma_ms: Annotated[float, Field(gt=0, le=100)]


class Product(_Strict):
    """What the station does for one part number."""

    backend: str
    connection: str = ""
    magnetometer: str | int = "primary"
    # ``all`` (the default unless ``magnetometer`` names one sensor): every magnetometer the unit has, in
    # one tumble; or a list: device ids, or positions 1–9 in the firmware's order (1 = the primary).
    magnetometers: Literal["all"] | Annotated[list[int], Field(min_length=1)] | None = None
    # the mounting of every sensor against the unit's accelerometer: ``check`` (a wrong orientation
    # FAILs, naming the value that fixes it), ``fix`` (that value is written and proven with the
    # calibration), ``skip`` (not proven; recorded as skipped)
    orientation: Literal["check", "fix", "skip"] = "check"
    # the small misalignment left once the orientation is right (mounting_error_deg, still judged against
    # its limit): ``keep`` (the firmware holds the discrete orientation only) or ``write`` (written where
    # the firmware can hold any rotation — PX4 ≥ 1.15, external sensors: CAL_MAGn_ROLL/PITCH/YAW — and
    # proven like the calibration; a sensor that cannot hold one keeps its discrete orientation, said)
    misalignment: Literal["keep", "write"] = "keep"
    # the magnetometers' time skew against the accelerometer, which the firmware's message pipeline makes
    # and the mounting check must know where the tumble cannot tell it from a turned sensor (a two-axis
    # gimbal at constant rates): ``learn`` (from this station's own passing units of the part, once
    # enough have determined theirs), ``none`` (each unit on its own tumble), or ``{ms, sigma_ms}``
    time_skew: Literal["learn", "none"] | TimeSkew = "learn"
    # where the calibration is kept: ``parameters`` (the firmware's parameter storage, which a customer's
    # "reset to defaults" erases) or ``factory-storage`` (PX4's factory calibration store, loaded at boot
    # under the user's parameters: a reset brings it back); a backend without such a store refuses it
    persist: Literal["parameters", "factory-storage"] = "parameters"
    # factory-storage: the SYS_FAC_CAL_MODE the unit is left with (0: later calibrations by the user do
    # not overwrite the factory store), and whether to prove the store by resetting the unit's calibration
    # parameters and seeing the factory values come back after a reboot (a second reboot per unit)
    factory_cal_mode_after: Annotated[int, Field(ge=0, le=2)] = 0
    prove_factory_restore: bool = False
    # the serial rule of this part (see core/serials.py): a full-match regular expression and a length
    serial_pattern: str | None = None
    serial_max_length: Annotated[int, Field(ge=1, le=256)] = 64
    # ``upper`` (default): labels are printed upper case, so ``sn-lower-01`` typed on a keyboard with
    # Caps Lock off is the unit ``SN-LOWER-01``; ``exact``: the case is part of the serial
    serial_case: Literal["upper", "exact"] = "upper"

    @field_validator("serial_pattern")
    @classmethod
    def _pattern_compiles(cls, pattern: str | None) -> str | None:
        if pattern is not None:
            import re

            try:
                re.compile(pattern)
            except re.error as exc:
                raise ValueError(f"not a regular expression: {exc}") from None
        return pattern

    @model_validator(mode="after")
    def _pattern_can_match_folded_serials(self) -> Product:
        """A pattern that asks for lower-case letters refuses every serial once it is upper-cased."""
        pattern = self.serial_pattern or ""
        if self.serial_case == "upper" and "a-z" in pattern and "A-Z" not in pattern and "(?i)" not in pattern:
            raise ValueError(f"serial_pattern {pattern} asks for lower-case letters, but serial_case 'upper' "
                             "folds every serial to upper case: write the pattern in upper case, or set "
                             "serial_case: exact")
        return self
    soft_iron_model: Literal["auto", "full", "diagonal", "sphere"] = "auto"
    options: dict[str, Any] = Field(default_factory=dict)
    power: PowerConfig = Field(default_factory=PowerConfig)
    limits: LimitSet = Field(default_factory=dict)
    # the compasses' current interference: ``off`` (default), ``measure`` (swept and judged) or
    # ``compensate`` (also written as the firmware's current compensation and proven after the power cycle)
    interference: Literal["off", "measure", "compensate"] = "off"
    current_max_a: Annotated[float, Field(gt=0, le=500)] | None = None  # the sweep's top: the unit's hover current
    # a motor test may spin this product's motors (props off) when the station's current source is motor-test
    motor_test: bool = False

    @model_validator(mode="after")
    def _interference_has_a_current(self) -> Product:
        if self.interference != "off" and self.current_max_a is None:
            raise ValueError(f"interference: {self.interference} needs current_max_a (the current the sweep goes "
                             "up to, in A: the unit's hover current)")
        return self


class FieldSource(_Strict):
    type: str = "fixed"
    options: dict[str, Any] = Field(default_factory=dict)


class Acquisition(_Strict):
    """How a tumble is read.

    ``stop: determined`` (the default) ends the tumble as soon as every magnetometer's coverage is at
    ``coverage_target`` and the running fit's predicted σ (heading, offset) are at most
    ``sigma_margin`` × the station's limits for them, never before ``min_samples`` readings;
    ``samples`` is then the most it takes.  ``stop: samples`` always reads ``samples`` readings.
    ``wait_for_drift_test`` (default true): a determined tumble also waits until the fit's warm-up
    drift test can judge its readings (on an even sweep, not before it turns back); false for a line
    whose units are warm before they are calibrated, which saves up to half a sweep.
    ``retry_on_warm_up`` (default true): an attempt whose fit caught the offset drifting (a unit still
    warming up: readings set aside or the drift modelled) is measured again while ``retries`` remain.
    The salvaged fit is the offset *during* the warm-up, and the sensor goes on settling after it (the
    post-reboot field check failed such good units); the attempt after it is taken only where its
    offset agrees with the previous attempt's (beyond noise and the station's ``hard_iron_sigma_ut``
    limit it moved: measured again); the last attempt keeps its fit.
    ``warm_up_s`` (default 0: none): the tumble starts only once the unit has run this long by its
    own uptime (a unit powered on earlier starts at once).  The drift test cannot see a warm-up
    smaller than about 14 offset σ, so a line whose units warm up during calibration sets the time
    their offsets take to settle (see :mod:`magline.core.sequencer.warm_up`)."""

    stop: Literal["determined", "samples"] = "determined"
    min_samples: Annotated[int, Field(ge=12)] = 100
    sigma_margin: Annotated[float, Field(gt=0, le=1)] = 0.7
    wait_for_drift_test: bool = True
    retry_on_warm_up: bool = True
    warm_up_s: Annotated[float, Field(ge=0, le=3600)] = 0.0
    samples: Annotated[int, Field(ge=12)] = 600
    rate_hz: Annotated[float, Field(gt=0, le=1000)] = 50.0
    coverage_bins: Annotated[int, Field(ge=4, le=10000)] = 100
    coverage_target: Annotated[float, Field(ge=0, le=1)] = 0.5
    retries: Annotated[int, Field(ge=0, le=20)] = 2
    retry_delay_s: Annotated[float, Field(ge=0)] = 1.0
    timeout_s: Annotated[float, Field(gt=0)] = 120.0
    range_ut: Annotated[float, Field(gt=0)] | None = None

    @model_validator(mode="after")
    def _min_within_samples(self) -> Acquisition:
        if self.stop == "determined" and self.min_samples > self.samples:
            raise ValueError(f"min_samples ({self.min_samples}) cannot exceed samples ({self.samples}), "
                             "the most a determined tumble reads")
        return self


class FitSettings(_Strict):
    """How strictly the fit judges what it was given (see :class:`magline.core.fit.FitOptions`).

    ``gain_sigma`` is the spread of the raw-to-reference field ratio on this line's units; the
    per-unit ``field_error_pct`` measurement in the results shows it.  A tight, true value is
    what lets a unit that cannot be turned over (a 30 % cap) still be calibrated.
    """

    gain_sigma: Annotated[float, Field(gt=0, le=1)] = 0.05
    max_direction_sigma_deg: Annotated[float, Field(gt=0, le=45)] = 1.0


class VerifySettings(_Strict):
    """How the verify phase proves the calibration after the power cycle.

    ``field_tolerance_pct``: the firmware's own calibrated output (where the backend can read it)
    must have the reference field's magnitude within this share; a calibration written to the
    wrong slot, with a wrong sign or unit, reads far off.
    """

    field_tolerance_pct: Annotated[float, Field(gt=0, le=50)] = 3.0


# Not the process's figures, so not reviewed by default: the count of attempts, and the σ of the
# measurement.  A determined tumble ends when its σ reach the stop rule's target, so they cluster just
# under it and a unit ended otherwise sits far off that tight band: on a simulated line of one design
# (benchmarks/review_flags.py, 200 good units reviewed) these four drew 29 of the review's 54 flags,
# every one for an uncertainty larger than the cluster and still inside its limit, which validate judges.
NOT_PROCESS_FIGURES = ("attempts", "hard_iron_sigma_ut", "direction_sigma_deg", "mounting_sigma_deg",
                       "drift_detectable_ut", "time_skew_sigma_ms", "time_skew_own_sigma_ms",
                       "interference_sigma_ut_per_a")


class ReviewSettings(_Strict):
    """The in-run process review: each numeric measurement of a unit that passed its limits is
    compared with the same measurement of the last ``window`` passing units of the same part on
    the same line; outside median ± ``sigma``·σ (robust) it is flagged for engineering review —
    the unit still passes.  With fewer than ``min_units`` such units there is no flag, and the
    record says why.  ``exclude``: measurements whose spread is not a process figure — by default the
    count of attempts and the uncertainties of the measurement itself (:data:`NOT_PROCESS_FIGURES`)."""

    enabled: bool = True
    window: Annotated[int, Field(ge=5, le=100_000)] = 200
    min_units: Annotated[int, Field(ge=5)] = 30
    sigma: Annotated[float, Field(gt=0, le=10)] = 3.0
    exclude: list[str] = Field(default_factory=lambda: list(NOT_PROCESS_FIGURES))

    @model_validator(mode="after")
    def _enough(self) -> ReviewSettings:
        if self.min_units > self.window:
            raise ValueError(f"min_units ({self.min_units}) cannot exceed window ({self.window})")
        unknown = [n for n in self.exclude if n not in KNOWN_LIMIT_NAMES]
        if unknown:
            raise ValueError(f"exclude: unknown measurement(s) {', '.join(unknown)}")
        return self


class Results(_Strict):
    """One results store: ``sqlite`` (``path``, relative to the station file), ``sql`` (``url_env``:
    the environment variable holding the server's URL — never the URL itself), or a plugin's sink
    with its own ``options`` (validated against the model the plugin registered)."""

    sink: str = "sqlite"
    path: str = "magline-results.sqlite"
    url_env: Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")] | None = None
    outbox: str = "magline-outbox.sqlite"  # ``sql``: records are committed here first, then forwarded
    reports: str | None = None  # a folder (relative to the station file): the unit's HTML report after each run
    options: dict[str, Any] = Field(default_factory=dict)  # a plugin sink's own settings


def _one_or_many(value: Any) -> Any:
    """``results:`` may be one store (a mapping, as it always was) or a list of stores."""
    return [value] if isinstance(value, dict) else value


class Motion(_Strict):
    """What turns the units during acquisition: ``operator`` (the default: a person tumbles the unit
    or the fixture, prompted by the screen) or a plugin's motion (e.g. ``gimbal``) with its options.
    On a station with slots, one motion serves every slot."""

    type: str = "operator"
    options: dict[str, Any] = Field(default_factory=dict)


class Slot(_Strict):
    """One position on a shared fixture (gimbal, coil, tumble cradle): its own DUT link and,
    optionally, its own power control; everything else comes from the part's product entry.
    ``options`` are merged over the product's options (e.g. a storage path per slot)."""

    id: Annotated[str, Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")]
    part: str
    connection: str | None = None
    options: dict[str, Any] = Field(default_factory=dict)
    power: PowerConfig | None = None


VERDICT_ACTIONS = {
    "pass": "Put the unit with the good units",
    "review": "Put the unit with the good units; engineering reviews the flagged figures",
    "fail": "Put the unit in the reject bin",
    "error": "The station could not judge the unit: test it again; call the technician if it happens again",
    "aborted": "Test the unit again",
    "incomplete": "Test the unit again",
}


class Prompts(_Strict):
    """What the operator is told.  ``verdicts``: what to do with the unit after each verdict (pass,
    review, fail, error, aborted), in the line's own words where it sets them."""

    serial: str = "Scan the unit's serial number"
    tumble: str = "Tumble the unit slowly through all orientations"
    retry: str = "Coverage too low — tumble again, covering every side"
    # a tumble stopped because the unit was only turned flat, about its vertical (core/acquisition/tumble_stop.py)
    spun_only: str = "Only turned flat — tumble again, tipping the unit onto every side, nose and tail"
    verdicts: dict[Literal["pass", "review", "fail", "error", "aborted", "incomplete"], str] = Field(
        default_factory=dict)

    def action(self, verdict: str) -> str:
        return self.verdicts.get(verdict) or VERDICT_ACTIONS.get(verdict, "")  # type: ignore[call-overload]


class Station(_Strict):
    station: StationInfo
    products: Annotated[dict[str, Product], Field(min_length=1)]
    default_part: str | None = None
    field_source: FieldSource = Field(default_factory=FieldSource)
    acquisition: Acquisition = Field(default_factory=Acquisition)
    fit: FitSettings = Field(default_factory=FitSettings)
    verify: VerifySettings = Field(default_factory=VerifySettings)
    limits: LimitSet = Field(default_factory=dict)
    # every store gets every record; the first is the station's own (run ids, history, statistics,
    # process review, reports)
    results: Annotated[list[Results], BeforeValidator(_one_or_many), Field(min_length=1)] = Field(
        default_factory=lambda: [Results()])
    review: ReviewSettings = Field(default_factory=ReviewSettings)
    prompts: Prompts = Field(default_factory=Prompts)
    motion: Motion = Field(default_factory=Motion)
    slots: list[Slot] = Field(default_factory=list)
    current_source: CurrentSourceConfig | None = None
    interference: InterferenceSettings = Field(default_factory=InterferenceSettings)
    # settings of the plugins that listen to the run (a plant feed, a dashboard): ``plugins.<section>``, each
    # validated by the model its plugin registered (``magline_register_plugin_options``) when plugins load
    plugins: dict[str, dict[str, Any]] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _a_current_source_for_the_sweep(self) -> Station:
        sweeping = [part for part, product in self.products.items() if product.interference != "off"]
        if sweeping and self.slots:
            raise ValueError(f"products {', '.join(sweeping)} measure their current interference, which needs each "
                             "unit's own power path and current source: not on a station with slots")
        if sweeping and self.current_source is None:
            raise ValueError(f"products {', '.join(sweeping)} measure their current interference, but the station "
                             "names no current_source (electronic-load or motor-test) to draw the current")
        if self.current_source is not None and self.current_source.type == "motor-test":
            refused = [part for part in sweeping if not self.products[part].motor_test]
            if refused:
                raise ValueError(f"the current source is motor-test, but products {', '.join(refused)} do not say "
                                 "motor_test: true (a motor test never spins a product's motors unless its entry "
                                 "allows it)")
        return self

    @field_validator("default_part")
    @classmethod
    def _a_product(cls, part: str | None, info: ValidationInfo) -> str | None:
        """Reported at ``default_part``'s own line, with the other problems of the file."""
        products = info.data.get("products") or {}
        if part is not None and products and part not in products:
            import difflib

            close = difflib.get_close_matches(part, list(products), n=1, cutoff=0.6)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ValueError(f"{part!r} is not one of the products{hint}; products: {', '.join(products)}")
        return part

    @field_validator("results")
    @classmethod
    def _reports_from_the_main_store(cls, stores: list[Results]) -> list[Results]:
        if any(r.reports is not None for r in stores[1:]):
            raise ValueError("reports: is read from the first results store only (the station's own)")
        return stores

    @property
    def main_results(self) -> Results:
        """The station's own results store (the first of ``results``)."""
        return self.results[0]

    @field_validator("slots")
    @classmethod
    def _slots_known(cls, slots: list[Slot], info: ValidationInfo) -> list[Slot]:
        """Every slot problem at once, reported at the ``slots`` key (its line in the file)."""
        products = info.data.get("products") or {}
        problems, seen = [], set()
        for index, slot in enumerate(slots):
            if slot.id in seen:
                problems.append(f"slot id {slot.id!r} is used twice (slot ids must be unique)")
            seen.add(slot.id)
            if products and slot.part not in products:
                problems.append(f"slot {slot.id} (item {index + 1}): part {slot.part!r} is not one of the products "
                                f"({', '.join(products)})")
        if problems:
            raise ValueError("; ".join(problems))
        return slots

    def slot(self, slot_id: str) -> Slot:
        for slot in self.slots:
            if slot.id == slot_id:
                return slot
        raise KeyError(f"no slot {slot_id!r} on station {self.station.id} (slots: "
                       f"{', '.join(s.id for s in self.slots) or 'none'})")

    def slot_product(self, slot: Slot) -> Product:
        """The part's product entry as this slot runs it: its own link, options and power."""
        product = self.products[slot.part]
        update: dict[str, Any] = {"options": {**product.options, **slot.options}}
        if slot.connection is not None:
            update["connection"] = slot.connection
        if slot.power is not None:
            update["power"] = slot.power
        return product.model_copy(update=update)

    def effective_limits(self, part: str) -> dict[str, Limit]:
        """Built-in defaults (mounting, agreement), line-wide limits, then the product's overrides."""
        defaults = {name: Limit(**rule) for name, rule in DEFAULT_LIMITS.items()}
        return {**defaults, **self.limits, **self.products[part].limits}

    def content_hash(self) -> str:
        """Stable hash of the whole validated station file (comments and layout do not count),
        stored with every result: which configuration judged the unit."""
        doc = self.model_dump(mode="json")
        return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]

    def limit_hash(self, part: str) -> str:
        """Stable hash of the effective limit set, stored with every result."""
        doc = {k: v.model_dump(exclude_none=True) for k, v in sorted(self.effective_limits(part).items())}
        return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]
