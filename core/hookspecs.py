"""Hook specifications: every point where a plugin can take part in a calibration.

Order of a unit's run (one direction of data: station file → sequencer → phases → record)::

    register_*  (once, at start-up: for ``magline``, once its command line is parsed)
    phase_started / phase_finished around each phase, operator_prompt and acquisition_progress
    during them:
      identify → connect → acquire (retries) → fit → validate → persist → verify → record
    unit_started (identify), attempt_ended (each attempt), record_unit (record): the results stores
    unit_finished (after the record is stored)

Hooks marked ``firstresult`` have one answer: the first plugin returning non-``None`` wins, so a
third-party plugin registered later (LIFO) can replace the core's default implementation.
A plugin is a plain module with functions named like these specs and decorated with
:data:`magline.plugin.hookimpl`, listed under the ``magline`` entry-point group::

    [project.entry-points.magline]
    my_dut = "my_package.my_dut_plugin"
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import pluggy

if TYPE_CHECKING:
    from pydantic import BaseModel

    from magline.core.fit import FitOptions, FitResult
    from magline.core.fit.samples_csv import RawSamples
    from magline.core.measurements import Measurement, Numeric
    from magline.core.record import AttemptRecord, PersistReport, PhaseResult, RunRecord, VerifyReport
    from magline.core.sequencer.context import Acquisition, RunContext

hookspec = pluggy.HookspecMarker("magline")


class Register(Protocol):
    """What every ``magline_register_*`` hook is given: ``register(name, factory, options=Model)``.

    ``Model`` (a pydantic model, optional) declares the options the name takes in a station file:
    ``magline check`` validates them with file, key and line, and the factory receives them
    validated (an instance of ``Model``).  Either may be named by where it lives —
    ``register(name, "package.module:create", options="package.module:Model")`` — and is then imported when
    first needed: the model when a station file uses the name (or a reference table lists it), the factory
    at its first call.  Why: every command registers every plugin, and what a plugin imports at registration
    costs each command's start, ``magline --help`` and ``magline check`` included."""

    def __call__(self, name: str, factory: Callable[..., Any] | str, options: type[BaseModel] | str | None = None,
                 stores: dict[str, str] | None = None) -> None: ...


# --------------------------------------------------------------------------- registration


@hookspec
def magline_register_dut_backends(register: Register) -> None:
    """Add DUT backends by name.  Called once at start-up.

    :param register: call ``register(name, factory, options=Model)`` once per backend;
        ``factory(product, options)`` receives the station file's product entry (for a slot: with
        the slot's connection and options) and ``products.<part>.options`` validated against
        ``Model`` (the raw mapping without one), and returns a :class:`~magline.plugin.DutBackend`.
        The name is what a station file writes under ``products.<part>.backend``; with ``Model``,
        ``magline check`` (and every command that loads the station) reports bad options with file,
        key and line before any unit is connected.  ``stores`` (optional) names where the backend can
        keep a calibration — the values a product's ``persist`` may take, each with a sentence for the
        engineer (``{"parameters": "…", "factory-storage": "…"}``; without it: ``parameters`` only); a
        product asking for another is refused by ``magline check`` with those sentences.  A backend
        offering ``factory-storage`` implements :class:`~magline.plugin.StoresFactoryCalibration`.

        An option naming a file (a simulated unit's memory) declared :data:`~magline.plugin.StationPath`
        arrives resolved against the station file's folder, as the station's own paths are (the factory
        is not given that folder).
    """


@hookspec
def magline_connection_problem(backend: str, connection: str) -> str | None:
    """Say what is wrong with how a station file reaches a unit, before any unit is connected.  Called by
    ``magline check`` (and every command that loads a station) for each product's ``connection`` and each
    slot's, with the product's backend; every answer that is not ``None`` is a problem of the station file.

    :param backend: the product's DUT backend: answer for the backends your plugin registered, ``None`` for
        the others
    :param connection: the connection as the station file writes it
    :return: what is wrong, in a sentence naming the forms the backend takes (the file, line and key are
        added); ``None`` when it is well formed — whether a unit answers there is the connect phase's to find.
        :func:`magline.plugin.connection_problem` checks the usual forms.
    """


@hookspec
def magline_register_field_sources(register: Register) -> None:
    """Add field sources (the expected local field) by name.  Called once at start-up.

    :param register: call ``register(name, factory, options=Model)``; ``factory(station, options)``
        receives the whole station and ``field_source.options`` validated against ``Model``, and
        returns a :class:`~magline.plugin.FieldSource`: ``reference_field_ut()`` (called as
        each unit connects; raise :class:`~magline.plugin.FieldSourceError` to stop the batch
        when the cell's field cannot be trusted), ``finish_unit()`` (after every unit,
        also after errors) and ``close()``; ``reference_is_ambient = True`` when the unit sits in that
        field after its power cycle too (the verify phase then checks the firmware's calibrated
        output against it).  The name is the station file's ``field_source.type``.
        A source that generates the field itself (a coil) also implements the acquire and fit
        hooks for its stations (see ``plugins/helmholtz``).
    """


@hookspec
def magline_register_result_sinks(register: Register) -> None:
    """Add result stores by name.  Called once at start-up.

    :param register: call ``register(name, factory, options=Model)``; ``factory(station,
        station_dir, entry, options)`` receives the station, its folder, its ``results`` entry
        (:class:`~magline.core.station.schema.Results`) and that entry's ``options`` validated
        against ``Model`` (the raw mapping when no model was registered), and returns a
        :class:`~magline.plugin.ResultSink` (``begin``, ``save_attempt``, ``finish``,
        ``history``, ``close``; run ids and the ``history`` shape are defined there).  The name is
        what a ``results`` entry writes under ``sink``; a station may list several stores.
    """


@hookspec
def magline_register_power_controls(register: Register) -> None:
    """Add power-control methods by name.  Called once at start-up.

    :param register: call ``register(name, factory, options=Model)``; ``factory(power_config,
        station_dir, options)`` receives the product's ``power`` entry, the station's folder and
        ``power.options`` validated against ``Model``, and returns a
        :class:`~magline.plugin.PowerControl`.  The name is what a station file writes under
        ``products.<part>.power.method``; the core registers ``link-reboot``.  As for backends,
        ``options=Model`` lets ``magline check`` validate ``products.<part>.power.options``.
    """


@hookspec
def magline_register_current_sources(register: Register) -> None:
    """Add current sources (what draws the current of the interference sweep) by name.
    Called once at start-up.

    :param register: call ``register(name, factory, options=Model)``; ``factory(config, station_dir,
        options)`` receives the station's ``current_source`` entry, its folder and
        ``current_source.options`` validated against ``Model``, and returns a
        :class:`~magline.plugin.CurrentSource`: ``start(run)`` readies it for one unit (a motor test
        checks the propellers are off here), ``set_level(fraction)`` draws that fraction of the
        product's ``current_max_a`` (a motor test: of its throttle), ``measured_current_a()`` what it
        measures itself (None when it cannot: the unit's own reading is the reference then),
        ``stop()`` draws nothing again (always called, also after errors), ``close()`` at the end of
        the batch.  A source whose level lasts only a while once set (a motor test spins for the
        seconds it was asked) says so in an attribute ``level_lasts_s``: the sweep sets the level again
        before half of that has passed, however long a step reads.  The name is the station file's
        ``current_source.type``; ``plugins/current`` registers ``electronic-load`` and ``motor-test``.
    """


@hookspec
def magline_register_motions(register: Register) -> None:
    """Add motions (what turns the units during acquisition) by name.  Called once at start-up.

    :param register: call ``register(name, factory, options=Model)``; ``factory(station,
        station_dir, options)`` (``motion.options`` validated against ``Model``) returns a
        :class:`~magline.plugin.Motion`: ``start(round, slots)`` begins the pattern and
        returns once the fixture moves, ``stop()`` ends it, ``close()`` at the end of the batch.
        The name is the station file's ``motion.type``; the core registers ``operator`` (a person
        tumbles the unit, prompted by the acquire phase).  On a station with slots one motion
        serves every slot: the sequencer starts it once per shared acquisition round, for the slots
        that need samples in that round, and stops it when the last of them has its samples.
    """


class RegisterMeasurement(Protocol):
    """What ``magline_register_measurements`` is given: ``register(name, unit=…, meaning=…, possible=…)``."""

    def __call__(self, name: str, unit: str = "", meaning: str = "",
                 possible: tuple[float, float] = (float("-inf"), float("inf"))) -> None: ...


@hookspec
def magline_register_measurements(register: RegisterMeasurement) -> None:
    """Declare the measurements the plugin produces.  Called once at start-up, before
    any station file is read.

    :param register: call ``register(name, unit="°C", meaning="…", possible=(low, high))`` once per
        measurement.  A declared name may be limited in a station file (``limits:`` or a product's, a
        sensor's ``mag2.<name>``) like magline's own: ``magline check`` validates the limit (and refuses
        one outside ``possible``), the limit set's hash covers it, the unit is judged on it, and
        ``magline spc``, ``export``, the report and the screen show it.  The plugin produces it from
        ``magline_validate`` or ``magline_validate_unit`` with ``run.measured(name, value)`` (judged
        against the station's limit, in the declared unit).  A name of magline's own, or one another
        plugin declared, is a :class:`PluginError`.
    """


@hookspec
def magline_register_plugin_options(register: Callable[[str, type[BaseModel] | str], None]) -> None:
    """Declare a section of the station file's ``plugins:`` for a plugin that is not a registered backend,
    sink or source — a listener such as a plant feed.  Called once at start-up.

    :param register: call ``register(section, Model)`` (or ``register(section, "package.module:Model")``,
        imported when a station file has the section): ``plugins.<section>`` in a station file is
        validated against the pydantic ``Model`` by ``magline check`` (file, key and line), and the plugin
        reads it during a run with ``run.plugin_options(section)`` (an instance of ``Model``; None when the
        station file has no such section: the plugin then does nothing).  A section registered twice, or a
        ``plugins:`` section no plugin registered, is an error naming it.
    """


@hookspec
def magline_add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Add sub-commands to the ``magline`` command line.  Called once, before arguments are parsed.

    :param subparsers: the command line's sub-parser collection; call
        ``subparsers.add_parser(name, help=...)`` and ``parser.set_defaults(handler=fn)``, where
        ``fn(args) -> int`` runs the command and returns its exit code.  Keep imports inside ``fn``
        so that ``magline --help`` stays fast.  (The simulators add ``magline sim`` this way:
        ``magline.sim.commands``.)
    """


# --------------------------------------------------------------------------- phases


@hookspec(firstresult=True)
def magline_acquire(run: RunContext, attempt: int) -> Acquisition | None:
    """Acquire raw samples for one attempt.  Called once per attempt until the samples reach the
    coverage target and the fit accepts them.

    :param run: the unit's run context (station, product, connected DUT, listeners).
        ``run.retry_advice`` says why a retry is needed when the fit refused the last attempt
        (None when coverage was too low): show it to the operator.
    :param attempt: 1 for the first acquisition, 2 for the first retry, ...
    :return: the samples with their live coverage figure.  The sequencer keeps every attempt
        and stores its raw data before anything is fitted.
    """


@hookspec(firstresult=True)
def magline_fit(run: RunContext, samples: RawSamples, options: FitOptions) -> FitResult | None:
    """Fit hard and soft iron.  Called on every attempt that reached coverage, right after its raw
    data are stored, until one is accepted.

    :param samples: raw samples (µT), with time and temperature where the DUT gives them.
    :param options: model (full/diagonal/sphere as the DUT can hold), reference field, range,
        the station's ``fit`` settings.
    :return: a :class:`~magline.plugin.FitResult`; raise
        :class:`~magline.plugin.FitRefused` when the data cannot determine the calibration:
        the sequencer then retries the acquisition with the refusal's advice as the prompt.
    """


@hookspec
def magline_validate(run: RunContext, fit: FitResult) -> list[Measurement]:
    """Produce measurements judged against the station's limits.  Every plugin may contribute.

    :param fit: the accepted fit.
    :return: a list of measurements (numeric with verdicts, arrays, JSON); the unit fails when
        any numeric verdict is ``fail``.  Persist is only called when none failed.
    """


@hookspec
def magline_validate_unit(run: RunContext, fits: dict[int, FitResult]) -> list[Measurement]:
    """Judge the unit as a whole once every magnetometer is fitted: each sensor's mounting against
    the unit's accelerometer, the agreement between sensors.  Called after :func:`magline_validate`
    (which judges one fit at a time; for sensors after the primary its names get the sensor's
    prefix, ``mag2.``), with every plugin contributing.

    :param fits: the accepted fit of every magnetometer calibrated in this run, by device id, the
        primary first (``run.magnetometers`` says which sensor each is; ``run.attempts[-1]`` holds
        their readings and the accelerometer's).
    :return: measurements judged against the station's limits (a pair's names carry both sensors'
        prefixes, ``mag1-mag2.``).  The core's mounting check leaves its decisions for the persist
        phase in ``run.orientation_fixes`` and ``run.rotation_writes``; a plugin keeps its own in
        ``run.state``.
        Raise :class:`~magline.plugin.StationFault` when the station cannot judge (no
        accelerometer to prove a mounting): the unit is an ERROR.
    """


@hookspec(firstresult=True)
def magline_persist(run: RunContext, fit: FitResult) -> PersistReport | None:
    """Write the calibration into the DUT's parameters and force it to storage.

    Called only when validation passed.  The default reads the parameters before, writes the
    backend's mapping of every fitted magnetometer (``run.fits``; ``fit`` is the primary's) and the
    orientations the mounting check asked to fix, checks every echo value and commits.

    :return: parameters before and written; raise :class:`~magline.plugin.DutError` on refusal.
    """


@hookspec(firstresult=True)
def magline_verify_persistence(run: RunContext, persisted: PersistReport) -> VerifyReport | None:
    """Power-cycle the DUT and prove the calibration survived.  Called after a successful persist.

    :param persisted: what :func:`magline_persist` wrote.
    :return: read-back values, mismatches and power-cycle figures; the unit fails on any mismatch
        or when the calibrated sensor is missing after the cycle.
    """


# --------------------------------------------------------------------------- the record


@hookspec
def magline_unit_started(run: RunContext) -> str | None:
    """The unit was accepted (identify phase, before its link is opened): ``run.record`` holds its
    serial, part, station and limit set.  The core's store listener (``results_store``) begins the
    run in ``run.results`` and sets ``run.record.run_id``; another store (a plant system) may begin
    its own.

    :return: the store's name when it began the run, None from a listener that keeps no record.  At
        least one answer is required: a unit no store heard of is an ERROR, never run unrecorded.
        Raise :class:`~magline.plugin.StationFault` when the store cannot take it (ERROR).
    """


@hookspec
def magline_attempt_ended(run: RunContext, attempt: AttemptRecord) -> str | None:
    """An acquisition attempt ended — accepted, refused for coverage, or interrupted by a lost link
    or an abort — before anything is fitted: store its raw readings now (``attempt.raw``,
    ``attempt.more`` for the other compasses), so they survive whatever follows.

    :return: the store's name when it kept the readings; at least one answer is required (raw data
        nobody kept make the unit an ERROR).  Raise :class:`~magline.plugin.StationFault` when the
        store cannot take them.
    """


@hookspec
def magline_record_unit(run: RunContext, record: RunRecord) -> str | None:
    """The unit's verdict is final, the DUT released: store the whole record (verdict, cause, phases,
    measurements, parameters before, written and read back).  Called once, in the record phase.

    :return: where the record is kept in the operator's words (a file, a server, an outbox),
        ``record.store`` joins every answer.  At least one answer is required, and a store that
        raises makes a PASS or FAIL an ERROR: a judgement nobody can trace does not count.
    """


# --------------------------------------------------------------------------- listeners


@hookspec
def magline_phase_started(run: RunContext, phase: str) -> None:
    """A phase begins (operator views, logging).  ``phase`` is one of the sequencer's phase names."""


@hookspec
def magline_phase_finished(run: RunContext, phase: str, result: PhaseResult) -> None:
    """A phase ended with its outcome (pass/fail/error/skipped), duration and log lines."""


@hookspec
def magline_acquisition_progress(run: RunContext, attempt: int, samples: int, coverage: float,
                                 target: float, bins: Sequence[int] | None, n_bins: int | None) -> None:
    """Live acquisition figures, called as samples arrive (coverage is a fraction 0..1).

    :param samples: readings read so far in this attempt; never decreasing (a long tumble keeps at most
        ``acquisition.samples`` of them, letting every other one go, but the count shown goes on).

    :param bins: the direction bins behind ``coverage`` (indices into
        :func:`magline.plugin.fibonacci_sphere` of ``n_bins``), for a view that lights
        them up; a coil's schedule gives the field directions it applied (its schedule is made of
        those points); None when the acquisition has no directions to show.
    :param n_bins: how many bins the sphere has (the station's ``acquisition.coverage_bins``; a
        coil's schedule: its ``directions``).  ``run.unit_moves`` tells a view whether the operator
        turns the unit (sides still to turn) or the field turns round it.
    """


@hookspec
def magline_acquisition_stopped(run: RunContext, attempt: int, reason: str, after_s: float, readings: int,
                                predicted: dict[str, dict[str, float]]) -> None:
    """An attempt's tumble ended, before its fit is judged: an operator view says "determined after
    N s" (or that the most readings were taken) and can tell the operator to stop moving the unit.

    :param reason: ``"determined"`` (coverage and predicted uncertainties inside the station's
        limits, and the mounting's errors clear of theirs), ``"stalled"`` (short of its target, the
        tumble could not reach it: turned about the vertical only, or no new direction lately; the
        operator is asked again), ``"samples"`` (``acquisition.samples``
        read), ``"timeout"`` (a determined tumble reached ``acquisition.timeout_s`` with readings
        enough to judge), or ``"stream ended"``.
    :param after_s: seconds of tumbling (from the motion's start for this unit).
    :param readings: distinct readings of the primary magnetometer read in the attempt (as the last
        progress said; a thinned tumble keeps fewer).
    :param predicted: when determined, the running fit's predicted σ per sensor (its measurement
        prefix, ``""`` for the primary) by measurement name (``direction_sigma_deg``,
        ``hard_iron_sigma_ut``, ``mounting_sigma_deg`` …), with the mounting's errors the stop judged
        clear of their limits (``mounting_error_deg``, ``inclination_error_deg``); empty otherwise.
    """


@hookspec
def magline_waiting(run: RunContext, what: str, elapsed_s: float, limit_s: float | None) -> None:
    """A long wait of the station is under way (the unit warming up before its tumble, the power
    cycle and the new boot): called about once a second, from a timer thread, so that an operator
    view can show a countdown.  :func:`magline_wait_ended` says when it is over.

    :param what: what the station waits for, in the operator's words.
    :param elapsed_s: seconds since the wait began.
    :param limit_s: when the station gives up (None when the backend does not say).
    """


@hookspec
def magline_wait_ended(run: RunContext, what: str, waited_s: float) -> None:
    """The wait announced by :func:`magline_waiting` is over, whatever ended it (what it waited for
    came, its limit ran out, the operator aborted, the link was lost): called once per wait, from the
    unit's thread, after its last :func:`magline_waiting` call and before the station goes on.  An
    operator view takes the countdown down here rather than guessing the end from what comes next.

    :param what: the same words as the wait's :func:`magline_waiting` calls.
    :param waited_s: seconds the wait lasted.
    """


@hookspec
def magline_motion_started(round: int, slots: list[str], motion: str) -> None:
    """The shared motion began an acquisition round (slot-aware views; per-unit plugins can ignore it).

    Called once per round, before any slot reads samples in it, from the thread of the slot that
    completed the round's line-up.

    :param round: 1 for the first pattern of the batch, 2 for the first shared retry, ...
    :param slots: the slot ids reading samples in this round (on a station without slots: ``[""]``);
        slots that already have an accepted attempt are not among them.
    :param motion: the station's ``motion.type``.
    """


@hookspec
def magline_motion_stopped(round: int, slots: list[str], motion: str) -> None:
    """The shared motion ended a round: every slot of ``slots`` has its samples, or left the round
    (link lost, abort).  Called once per round, after :func:`magline_motion_started`."""


@hookspec
def magline_tilt_guidance(run: RunContext, guidance: dict) -> None:
    """On a turntable (a motion that ``TurnsForTilts``), each time what the station asks of the cradle
    changes: ``guidance`` holds ``state`` (``tilt``: waiting for the operator, ``turning``, ``stalled``),
    ``asked`` (the tilt in words), ``pitch_deg`` and ``roll_deg`` (for a picture of the cradle), ``step``
    (the how-many-th tilt of the round), ``found`` (the tilt the accelerometer sees instead, in words, or
    None) and ``why`` (what stalled).  For outputs (the console, the screen); the words to the operator
    come as :func:`magline_operator_prompt` too."""


@hookspec
def magline_operator_prompt(run: RunContext, message: str) -> None:
    """Something the operator must do now (tumble, tumble again, scan)."""


@hookspec(firstresult=True)
def magline_operator_confirm(run: RunContext, question: str, timeout_s: float) -> bool | None:
    """The station needs the operator's yes before something that could hurt — the propellers off
    before a motor test spins them.  Called on the unit's thread; an answerer blocks until
    the operator answers or ``timeout_s`` has passed.

    :returns: True (yes), False (no, or no answer in time: never a yes by default), or None when this
        listener has no operator at it (a console without a terminal) — the next one is asked.  Nobody
        answering at all is the caller's to refuse.
    """


@hookspec
def magline_unit_judged(run: RunContext, measurements: list[Numeric]) -> None:
    """The validate phase found every measurement inside its limits (called before persist, never
    for a FAIL).  A listener may compare the unit with the process — the core's in-run review marks
    a measurement far from the recent units ``Verdict.REVIEW`` and writes ``run.record.review`` and
    ``review_note`` — but must not fail the unit: a REVIEW is for engineering, the unit passes.

    :param measurements: the unit's numeric measurements with their verdicts (all PASS or REVIEW).
        ``run.results`` is the station's results store (``series`` for the process's history).
    """


@hookspec
def magline_unit_finished(run: RunContext, record: RunRecord) -> None:
    """The unit's run is complete and stored; ``record`` holds the verdict and everything measured.

    A listener (a plant feed, a screen): an exception it raises is caught and said — which plugin, which
    hook, the message — in ``record.listener_faults`` and as a warning; the verdict, the exit code and a
    ``--loop`` batch go on.  (The same holds for ``magline_phase_started`` and ``magline_phase_finished``.)
    Every product's units are heard: a plugin keeps to its own by ``run.part`` or ``record.part``.
    Keeping a record is ``magline_record_unit``'s, whose failure is the unit's ERROR."""
