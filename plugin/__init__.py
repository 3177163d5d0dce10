"""magline's public face for plugin authors: everything a DUT backend, field source, motion, power
control or results sink may use, in one import (``from magline.plugin import hookimpl, DutError, …``).

Why one face: ``magline.core`` is the executive's own code and moves as it grows; a plugin that
imports from here keeps working when it does.  The built-in plugins, the example plugin
(``examples/acme-magline``) and ``docs/plugins.md`` use nothing else of magline (a test guards it);
what a plugin's *tests* need is :mod:`magline.testing`.

What is here, by role:

* registration: :data:`hookimpl` (the hooks and their order: ``docs/plugins.md``) and the contracts
  a registered factory returns: :class:`DutBackend`, :class:`FieldSource`, :class:`Motion`,
  :class:`PowerControl` (a power cut's new boot: :func:`await_boot_after_cut`), a turntable's
  :class:`TurnsForTilts` with its cradle's :class:`Tilt` (:func:`tilt_words`), :class:`ResultSink`,
  :class:`CurrentSource` (the interference sweep's current; its errors :class:`CurrentSourceError`);
* the DUT contract: :class:`DutBackend`, :class:`UnitInfo`, :class:`Magnetometer`, :class:`SampleChunk`,
  :data:`ParamValue`, its errors (:class:`DutError`, :class:`LinkError`, :class:`UnansweredRequest`,
  :class:`NotRestored`, :class:`StationFault`, :class:`PowerError`, :class:`FieldSourceError`) and the
  helpers every MAVLink-like backend needs (:func:`await_new_boot` — :class:`OldBootRunning` when the old
  boot answers —, :func:`require_same_vehicle`,
  :func:`prove_unechoed_write`, :func:`float32_equal`);
* optional capabilities a backend has by having the method (the core asks ``isinstance(dut, …)``):
  :class:`CalibratesSeveral`, :class:`ReportsSensorsPresent`, :class:`WritesOrientation`,
  :class:`WritesRotation`, :class:`StoresFactoryCalibration`, :class:`ReportsUptime`, :class:`HasBootTimeout`,
  :class:`ReadsCalibratedField`,
  :class:`ReadsCalibratedFields`, :class:`ReadsRawAndCalibrated` (answering a :class:`CalibratedBesideRaw`),
  :class:`CompensatesCurrent`, :class:`RunsMotorTest`;
* links to hardware: :func:`get_listening`, :func:`stall_s`, :data:`SLICE_S` (reading a queue while
  the link may die), :class:`Refusals` and :data:`NOTHING_LISTENS_S` (a first connection refused that long
  says nothing listens there, at once), :class:`RepeatFilter`, :class:`ReadingsAtRest`, :class:`SensorStreams`,
  :func:`untruncate_mg`,
  :data:`INT16_MG_RANGE_UT` (MAVLink's int16 milligauss), :class:`ScpiInstrument`, :class:`InstrumentError`;
* MSP (INAV's protocol): :class:`MspClient`, :class:`MspParser`, :class:`MspFrame`, :func:`encode_msp_v1`,
  :func:`encode_msp_v2`, :func:`crc8_dvb_s2`, :class:`MspRefused`, :class:`MspTimeout`, the command numbers
  :class:`Msp`, a setting's description :class:`SettingInfo` (:func:`parse_setting_info`,
  :func:`encode_setting_info`), :data:`INAV_ARMED_FLAG` and INAV's sensor alignments
  (:data:`INAV_ALIGNMENTS`, :data:`INAV_ALIGNMENT_NAMES`, :data:`INAV_COMPASS_DEFAULT_ALIGNMENT`,
  an external compass's :func:`inav_external_rotation` and :func:`inav_external_angles`; INAV's axes,
  forward-left-up, against magline's: :data:`INAV_TO_FRD`, :func:`inav_rotation_in_frd`),
  what a station file's ``connection`` may be: :class:`ConnectionForms`, :func:`connection_problem`;
  a board on a serial port: :class:`SerialAddress`, :class:`SerialPortWatch` (present, permitted, not held,
  the same board after its reboot), :class:`UsbIdentity`, :func:`list_ports`, :data:`SERIAL_HINT`,
  :func:`mavlink2_frame_bytes` (a stream's bytes against what a UART carries);
* frames: :func:`orientation_matrix` (a firmware orientation value's rotation), :func:`configured_rotation`
  (the rotation a firmware applies to a :class:`Magnetometer` now);
* the run: :class:`RunContext`, :class:`Acquisition`, :class:`ImuSeries`, :class:`RawSamples`,
  :func:`wait_or_abort`, the station's :class:`Station`, :class:`Product`, :class:`PowerConfig`,
  :class:`CurrentSourceConfig`, and a path option read as the station file's own paths are,
  :data:`StationPath`;
* fitting and stopping (field sources that run their own schedule): :class:`FitOptions`,
  :class:`FitResult`, :class:`FitRefused`, :func:`fit_affine`, :func:`fibonacci_sphere`,
  :class:`StopRule`, :func:`stop_rule`, :class:`Fluxgate`, :class:`ReferenceOptions`;
* results: what a sink stores and how it is judged — :class:`RunRecord`, :class:`AttemptRecord`,
  :class:`PhaseResult`, :class:`Outcome`, :class:`Measurement`, :class:`Numeric`, :class:`Verdict`, and
  the sink's contract :class:`ResultSink` with the history it answers (:class:`HistoryRun`,
  :class:`HistoryAttempt`, :class:`HistoryFailure`) and its optional capabilities (:class:`SaysWhere`,
  :class:`KeepsSeries`, :class:`HoldsRecordsInSql`, :class:`ReadsInSql`, :class:`ClaimsSlots`,
  :class:`ForwardsQueued`).
"""

from __future__ import annotations

from magline.core.lazy import lazy_names

# Where each name of the face lives.  Why looked up on first use (PEP 562) rather than imported here: every
# command imports every plugin, and each plugin imports this face; importing all it names (SciPy's rotations,
# the results store's SQLAlchemy, the fit) cost each command half a second before it did anything.
_HOME: dict[str, tuple[str, ...]] = {
    "magline.core.acquisition.tumble_stop": ("stop_rule",),
    "magline.core.dut": (
        "CalibratedBesideRaw", "CalibratesSeveral", "CompensatesCurrent", "DutBackend", "DutError", "HasBootTimeout",
        "LinkError", "Magnetometer", "NotRestored", "OldBootRunning", "ParamValue", "ReadsCalibratedField",
        "ReadsCalibratedFields", "ReadsRawAndCalibrated", "ReportsSensorsPresent", "ReportsUptime", "RunsMotorTest",
        "SampleChunk", "StoresFactoryCalibration", "UnansweredRequest", "UnitInfo", "WritesOrientation",
        "WritesRotation", "await_new_boot", "float32_equal", "prove_unechoed_write", "require_same_vehicle",
    ),
    "magline.core.faults": ("StationFault",),
    "magline.core.field": ("FieldSource", "FieldSourceError"),
    "magline.core.field.options": ("ReferenceOptions",),
    "magline.core.field.reference": ("Fluxgate",),
    "magline.core.fit": ("FitOptions", "FitResult"),
    "magline.core.fit.affine": ("fit_affine",),
    "magline.core.fit.coverage": ("fibonacci_sphere",),
    "magline.core.fit.result": ("FitRefused",),
    "magline.core.fit.running": ("StopRule",),
    "magline.core.fit.samples_csv": ("RawSamples",),
    "magline.core.interference.source": ("CurrentSource", "CurrentSourceError"),
    "magline.core.links.addresses": ("ConnectionForms", "connection_problem"),
    "magline.core.links.listening": ("SLICE_S", "get_listening", "stall_s"),
    "magline.core.links.msp": (
        "INAV_ALIGNMENT_NAMES", "INAV_ALIGNMENTS", "INAV_ARMED_FLAG", "INAV_COMPASS_DEFAULT_ALIGNMENT", "INAV_TO_FRD",
        "Msp", "MspClient", "MspFrame", "MspParser", "MspRefused", "MspTimeout", "SettingInfo", "crc8_dvb_s2",
        "encode_msp_v1", "encode_msp_v2", "encode_setting_info", "inav_external_angles", "inav_external_rotation",
        "inav_rotation_in_frd", "parse_setting_info",
    ),
    "magline.core.links.refusals": ("NOTHING_LISTENS_S", "Refusals"),
    "magline.core.links.readings": (
        "INT16_MG_RANGE_UT", "ReadingsAtRest", "RepeatFilter", "SensorStreams", "untruncate_mg",
    ),
    "magline.core.links.scpi": ("InstrumentError", "ScpiInstrument"),
    "magline.core.links.serial_port": (
        "SERIAL_HINT", "SerialAddress", "SerialAddressError", "SerialPortWatch", "UsbIdentity", "list_ports",
        "mavlink2_frame_bytes",
    ),
    "magline.core.measurements": ("Array", "Json", "Measurement", "Numeric", "Verdict"),
    "magline.core.motion": ("Motion", "TurnsForTilts"),
    "magline.core.motion.tilts": ("Tilt", "tilt_words"),
    "magline.core.mounting": ("ImuSeries", "orientation_matrix"),
    "magline.core.mounting.checks": ("configured_rotation",),
    "magline.core.plugins": ("hookimpl",),
    "magline.core.power": ("PowerControl", "PowerError", "await_boot_after_cut"),
    "magline.core.record": ("AttemptRecord", "Outcome", "PhaseResult", "RunRecord"),
    "magline.core.results.contract": (
        "ClaimsSlots", "ForwardsQueued", "HistoryAttempt", "HistoryFailure", "HistoryRun", "HoldsRecordsInSql",
        "KeepsSeries", "ReadsInSql", "ResultSink", "SaysWhere",
    ),
    "magline.core.sequencer.context": ("Acquisition", "RunContext"),
    "magline.core.sequencer.rounds": ("wait_or_abort",),
    "magline.core.station.paths": ("StationPath",),
    "magline.core.station.schema": ("CurrentSourceConfig", "PowerConfig", "Product", "Station"),
}
__all__, __getattr__, __dir__ = lazy_names(__name__, _HOME)
