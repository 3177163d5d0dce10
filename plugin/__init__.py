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
  the link may die), :class:`RepeatFilter`, :class:`ReadingsAtRest`, :class:`SensorStreams`, :func:`untruncate_mg`,
  :data:`INT16_MG_RANGE_UT` (MAVLink's int16 milligauss), :class:`ScpiInstrument`, :class:`InstrumentError`,
  MSP (INAV's protocol): :class:`MspClient`, :class:`MspParser`, :class:`MspFrame`, :func:`encode_msp_v1`,
  :func:`encode_msp_v2`, :func:`crc8_dvb_s2`, :class:`MspRefused`, :class:`MspTimeout`, the command numbers
  :class:`Msp`, a setting's description :class:`SettingInfo` (:func:`parse_setting_info`,
  :func:`encode_setting_info`), :data:`INAV_ARMED_FLAG` and INAV's sensor alignments
  (:data:`INAV_ALIGNMENTS`, :data:`INAV_ALIGNMENT_NAMES`, :data:`INAV_COMPASS_DEFAULT_ALIGNMENT`,
  an external compass's :func:`inav_external_rotation` and :func:`inav_external_angles`; INAV's axes,
  forward-left-up, against magline's: :data:`INAV_TO_FRD`, :func:`inav_rotation_in_frd`),
  a board on a serial port: :class:`SerialAddress`, :class:`SerialPortWatch` (present, permitted, not held,
  the same board after its reboot), :class:`UsbIdentity`, :func:`list_ports`, :data:`SERIAL_HINT`,
  :func:`mavlink2_frame_bytes` (a stream's bytes against what a UART carries);
* frames: :func:`orientation_matrix` (a firmware orientation value's rotation), :func:`configured_rotation`
  (the rotation a firmware applies to a :class:`Magnetometer` now);
* the run: :class:`RunContext`, :class:`Acquisition`, :class:`ImuSeries`, :class:`RawSamples`,
  :func:`wait_or_abort`, the station's :class:`Station`, :class:`Product`, :class:`PowerConfig`,
  :class:`CurrentSourceConfig`;
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

from magline.core.acquisition.tumble_stop import stop_rule
from magline.core.dut import (
    CalibratedBesideRaw,
    CalibratesSeveral,
    CompensatesCurrent,
    DutBackend,
    DutError,
    HasBootTimeout,
    LinkError,
    Magnetometer,
    NotRestored,
    OldBootRunning,
    ParamValue,
    ReadsCalibratedField,
    ReadsCalibratedFields,
    ReadsRawAndCalibrated,
    ReportsSensorsPresent,
    ReportsUptime,
    RunsMotorTest,
    SampleChunk,
    StoresFactoryCalibration,
    UnansweredRequest,
    UnitInfo,
    WritesOrientation,
    WritesRotation,
    await_new_boot,
    float32_equal,
    prove_unechoed_write,
    require_same_vehicle,
)
from magline.core.faults import StationFault
from magline.core.field import FieldSource, FieldSourceError
from magline.core.field.reference import Fluxgate, ReferenceOptions
from magline.core.fit import FitOptions, FitResult
from magline.core.fit.affine import fit_affine
from magline.core.fit.coverage import fibonacci_sphere
from magline.core.fit.result import FitRefused
from magline.core.fit.running import StopRule
from magline.core.fit.samples_csv import RawSamples
from magline.core.interference.source import CurrentSource, CurrentSourceError
from magline.core.links.listening import SLICE_S, get_listening, stall_s
from magline.core.links.msp import (
    INAV_ALIGNMENT_NAMES,
    INAV_ALIGNMENTS,
    INAV_ARMED_FLAG,
    INAV_COMPASS_DEFAULT_ALIGNMENT,
    INAV_TO_FRD,
    Msp,
    MspClient,
    MspFrame,
    MspParser,
    MspRefused,
    MspTimeout,
    SettingInfo,
    crc8_dvb_s2,
    encode_msp_v1,
    encode_msp_v2,
    encode_setting_info,
    inav_external_angles,
    inav_external_rotation,
    inav_rotation_in_frd,
    parse_setting_info,
)
from magline.core.links.readings import INT16_MG_RANGE_UT, ReadingsAtRest, RepeatFilter, SensorStreams, untruncate_mg
from magline.core.links.scpi import InstrumentError, ScpiInstrument
from magline.core.links.serial_port import (
    SERIAL_HINT,
    SerialAddress,
    SerialAddressError,
    SerialPortWatch,
    UsbIdentity,
    list_ports,
    mavlink2_frame_bytes,
)
from magline.core.measurements import Array, Json, Measurement, Numeric, Verdict
from magline.core.motion import Motion, TurnsForTilts
from magline.core.motion.tilts import Tilt, tilt_words
from magline.core.mounting import ImuSeries, orientation_matrix
from magline.core.mounting.checks import configured_rotation
from magline.core.plugins import hookimpl
from magline.core.power import PowerControl, PowerError, await_boot_after_cut
from magline.core.record import AttemptRecord, Outcome, PhaseResult, RunRecord
from magline.core.results.contract import (
    ClaimsSlots,
    ForwardsQueued,
    HistoryAttempt,
    HistoryFailure,
    HistoryRun,
    HoldsRecordsInSql,
    KeepsSeries,
    ReadsInSql,
    ResultSink,
    SaysWhere,
)
from magline.core.sequencer.context import Acquisition, RunContext
from magline.core.sequencer.rounds import wait_or_abort
from magline.core.station.schema import CurrentSourceConfig, PowerConfig, Product, Station

__all__ = [
    "INAV_ALIGNMENTS",
    "INAV_ALIGNMENT_NAMES",
    "INAV_ARMED_FLAG",
    "INAV_COMPASS_DEFAULT_ALIGNMENT",
    "INAV_TO_FRD",
    "INT16_MG_RANGE_UT",
    "SERIAL_HINT",
    "SLICE_S",
    "Acquisition",
    "Array",
    "AttemptRecord",
    "CalibratedBesideRaw",
    "CalibratesSeveral",
    "ClaimsSlots",
    "CompensatesCurrent",
    "CurrentSource",
    "CurrentSourceConfig",
    "CurrentSourceError",
    "DutBackend",
    "DutError",
    "FieldSource",
    "FieldSourceError",
    "FitOptions",
    "FitRefused",
    "FitResult",
    "Fluxgate",
    "ForwardsQueued",
    "HasBootTimeout",
    "HistoryAttempt",
    "HistoryFailure",
    "HistoryRun",
    "HoldsRecordsInSql",
    "ImuSeries",
    "InstrumentError",
    "Json",
    "KeepsSeries",
    "LinkError",
    "Magnetometer",
    "Measurement",
    "Motion",
    "Msp",
    "MspClient",
    "MspFrame",
    "MspParser",
    "MspRefused",
    "MspTimeout",
    "NotRestored",
    "Numeric",
    "OldBootRunning",
    "Outcome",
    "ParamValue",
    "PhaseResult",
    "PowerConfig",
    "PowerControl",
    "PowerError",
    "Product",
    "RawSamples",
    "ReadingsAtRest",
    "ReadsCalibratedField",
    "ReadsCalibratedFields",
    "ReadsInSql",
    "ReadsRawAndCalibrated",
    "ReferenceOptions",
    "RepeatFilter",
    "ReportsSensorsPresent",
    "ReportsUptime",
    "ResultSink",
    "RunContext",
    "RunRecord",
    "RunsMotorTest",
    "SampleChunk",
    "SaysWhere",
    "ScpiInstrument",
    "SensorStreams",
    "SerialAddress",
    "SerialAddressError",
    "SerialPortWatch",
    "SettingInfo",
    "Station",
    "StationFault",
    "StopRule",
    "StoresFactoryCalibration",
    "Tilt",
    "TurnsForTilts",
    "UnansweredRequest",
    "UnitInfo",
    "UsbIdentity",
    "Verdict",
    "WritesOrientation",
    "WritesRotation",
    "await_boot_after_cut",
    "await_new_boot",
    "configured_rotation",
    "crc8_dvb_s2",
    "encode_msp_v1",
    "encode_msp_v2",
    "encode_setting_info",
    "fibonacci_sphere",
    "fit_affine",
    "float32_equal",
    "get_listening",
    "hookimpl",
    "inav_external_angles",
    "inav_external_rotation",
    "inav_rotation_in_frd",
    "list_ports",
    "mavlink2_frame_bytes",
    "orientation_matrix",
    "parse_setting_info",
    "prove_unechoed_write",
    "require_same_vehicle",
    "stall_s",
    "stop_rule",
    "tilt_words",
    "untruncate_mg",
    "wait_or_abort",
]
