"""magline.testing: the public testing API for plugin authors (and magline's own tests).

What a DUT, field-source, motion or results-sink author needs without reading magline's internals:

* stations: :func:`station_file` (a station from a shipped example and a dict of changes, in a
  folder of yours), :func:`run_unit` (one unit through every phase, no waiting between attempts),
  :func:`check_station` (exactly the problems ``magline check`` prints);
* builders: :func:`make_fit` (a :class:`~magline.plugin.FitResult` from ``h``, ``S`` and the
  field, for testing a parameter conversion) and :func:`make_record`;
* known truth: :class:`SensorTruth`, :func:`random_truth`, :func:`earth_field_ned`,
  :func:`motion_directions` (the sensor model and operator motions magline's own accuracy
  benchmarks use);
* simulated flight controllers: :func:`px4_sim`, :func:`ardupilot_sim` (real MAVLink on a free
  loopback port), :func:`inav_sim` (INAV's MSP) and the connection string a station uses for them;
* replay: :func:`mavlink_replay` plays the vehicle of a unit recorded on the line with
  ``magline run --record-mavlink FILE`` to your backend (a bug seen on the line becomes a test);
* conformance: :func:`check_dut_backend` runs the DUT-backend contract against your backend and
  its (simulated) device, :func:`check_result_sink` the results-sink contract against your sink,
  :func:`check_field_source` and :func:`check_power_control` theirs.

With magline installed, pytest loads :mod:`magline.testing.plugin` (entry point ``pytest11``):
its fixtures (``magline_station``, ``magline_run``, ``magline_px4``, ``magline_ardupilot``,
``magline_inav``, ``magline_mock_dut``, ``magline_results``) are
there for any test that names them, and do nothing otherwise.
"""

from magline.sim.truth import SensorTruth, earth_field_ned, gravity_body, motion_directions, random_truth
from magline.testing.builders import make_fit, make_record
from magline.testing.conformance import check_dut_backend, check_field_source, check_power_control, check_result_sink
from magline.testing.replay import mavlink_replay, read_tlog
from magline.testing.sims import SimulatedVehicle, ardupilot_sim, inav_sim, px4_sim
from magline.testing.stations import Problem, check_station, deep_update, run_unit, station_file

__all__ = [
           "Problem",
           "SensorTruth",
           "SimulatedVehicle",
           "ardupilot_sim",
           "check_dut_backend",
           "check_field_source",
           "check_power_control",
           "check_result_sink",
           "check_station",
           "deep_update",
           "earth_field_ned",
           "gravity_body",
           "inav_sim",
           "make_fit",
           "make_record",
           "mavlink_replay",
           "motion_directions",
           "px4_sim",
           "random_truth",
           "read_tlog",
           "run_unit",
           "station_file",
]
