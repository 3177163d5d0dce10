"""Every magnetometer's mounting proven against the unit's accelerometer, and the sensors against each
other (issue 26): the estimator on known synthetic truth, then whole units on the simulated ArduPilot
and PX4 over real MAVLink, and the mock's bad-input cases."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from simstation import FAST_SENSOR_HZ, run_unit, write_station
from sqlalchemy import create_engine, select

from magline.core.measurements import Verdict
from magline.core.mounting import (
    RIGHT_ANGLE,
    ImuSeries,
    MountingUnobservable,
    estimate_mounting,
    heading_agreement,
    orientation_matrix,
    orientation_name,
)
from magline.core.mounting.orientations import rotation_angle_deg
from magline.core.record import Outcome
from magline.core.results import raw_blob
from magline.core.results.tables import attempt_streams
from magline.sim import SimFaults, create_sim
from magline.sim.truth.imu import averaged_spiral, simulator_fields, skewed_tumble, tumble_with_imu

# A deviation a right estimate exceeds with a probability below 1e-5, in units of its own stated σ: the
# angle of a rotation whose three axes each have 1σ ≤ σ is beyond 5σ with probability 1.5e-5 (χ, 3
# degrees of freedom), a single normal figure with 6e-7.  Why not 3σ: a three-compass unit has three
# such angles, and 3σ is crossed by 2.9 % of right ones (a CI run FAILed a good compass at 2.3σ of
# a bound of 1° set when the simulators paired every reading exactly).
Z_NEVER = 5.0
AP_OPTIONS = {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0, "prearm_wait_s": 0.3}
PX4_OPTIONS = {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0, "save_settle_s": 0.1}


def tumble(mounted: np.ndarray, rng: np.random.Generator, **kwargs) -> tuple[np.ndarray, np.ndarray, ImuSeries]:
    """The simulators' spiral, every reading stamped at its instant (the same path for every seed)."""
    mag, t_mag, accel, t_acc = tumble_with_imu(mounted, rng, **kwargs)
    return mag, t_mag, ImuSeries(t_ms=t_acc, accel_mss=accel)


def hand_tumble(mounted: np.ndarray, rng: np.random.Generator, *, rate_dps: float = 90.0, skew_s: float = 0.04,
                **kwargs) -> tuple[np.ndarray, np.ndarray, ImuSeries]:
    """An operator's free tumble as a firmware streams it: each compass reading stamped ``skew_s``
    before it was taken (ArduCopter's ≈ 40 ms), to the next 50 Hz message."""
    mag, t_mag, accel, t_acc, _ = skewed_tumble(mounted, rng, rate_dps=rate_dps, skew_s=skew_s, **kwargs)
    return mag, t_mag, ImuSeries(t_ms=t_acc, accel_mss=accel)


def test_orientation_table_is_the_firmwares_rotate():
    v = np.array([1.0, 2.0, 3.0])
    assert orientation_matrix(2) @ v == pytest.approx([-2.0, 1.0, 3.0])  # Yaw90: x' = −y, y' = x
    assert orientation_matrix(8) @ v == pytest.approx([1.0, -2.0, -3.0])  # Roll180
    assert orientation_matrix(10) @ v == pytest.approx([2.0, 1.0, -3.0])  # Roll180Yaw90
    assert orientation_name(2) == "Yaw90" and orientation_name(8) == "Roll180"
    assert len(RIGHT_ANGLE) == 24
    assert all(rotation_angle_deg(a, b) > 80 for i, a in RIGHT_ANGLE.items() for j, b in RIGHT_ANGLE.items() if i < j)


def test_a_small_misalignment_and_the_inclination_are_recovered(rng):
    truth = Rotation.from_rotvec(np.radians([1.2, -0.8, 2.0])).as_matrix()
    mag, t_ms, imu = hand_tumble(truth, rng)
    estimate = estimate_mounting(mag, t_ms, imu)
    assert rotation_angle_deg(estimate.data_to_body, truth) < 0.3
    assert estimate.right_angle[0] == 0
    assert estimate.right_angle[1] == pytest.approx(rotation_angle_deg(truth, np.eye(3)), abs=0.3)
    assert estimate.inclination_deg == pytest.approx(62.0, abs=0.3)


def test_the_inclination_is_the_field_s_dip_whichever_branch_the_solver_ends_on(rng, monkeypatch):
    """The residuals hold the inclination through its sine, so 62° and 118° fit alike: a turntable's few
    tilts once let the solver end on 118° and a good unit FAILed on a 56° inclination error.  Made to end
    on the other branch, the estimate still says 62°."""
    import scipy.optimize

    solve = scipy.optimize.least_squares

    def other_branch(*args, **kwargs):
        fit = solve(*args, **kwargs)
        fit.x[3] = np.pi - fit.x[3]  # the same sine
        return fit

    monkeypatch.setattr(scipy.optimize, "least_squares", other_branch)
    mag, t_ms, imu = hand_tumble(np.eye(3), rng)
    estimate = estimate_mounting(mag, t_ms, imu)
    assert estimate.inclination_deg == pytest.approx(62.0, abs=0.3)
    assert rotation_angle_deg(estimate.data_to_body, np.eye(3)) < 0.3


def test_the_mountings_sigma_covers_its_error_and_one_reading_far_off_does_not_move_it(rng):
    """The σ is what the stop waits for and the record states: over many tumbles the error stays within
    it as a rotation's does (median error/σ at most a Maxwell median, 1.54, whose axes each have 1σ
    at most σ), although the hand's accelerations make neighbouring readings alike; and a reading 90°
    off (taken before the unit moved) leaves it as it was (it made it 9× larger, holding a tumble to
    its count)."""
    ratios, moved = [], []
    for _ in range(40):
        truth = Rotation.from_rotvec(rng.normal(size=3) * np.radians(0.7)).as_matrix()
        mag, t_ms, imu = hand_tumble(truth, rng, rate_dps=rng.uniform(30.0, 250.0), skew_s=rng.uniform(-0.1, 0.1))
        estimate = estimate_mounting(mag, t_ms, imu)
        ratios.append(rotation_angle_deg(estimate.data_to_body, truth) / estimate.sigma_deg)
        off = mag.copy()
        off[0] = Rotation.from_rotvec([0.0, np.pi / 2, 0.0]).apply(off[0])
        moved.append(estimate_mounting(off, t_ms, imu).sigma_deg / estimate.sigma_deg)
    assert np.median(ratios) <= 1.54
    assert max(moved) < 1.2


@pytest.mark.parametrize("value", sorted(RIGHT_ANGLE))
def test_every_right_angle_mounting_is_named(value, rng):
    mag, t_ms, imu = hand_tumble(orientation_matrix(value), rng, seconds=30.0)
    found, residual = estimate_mounting(mag, t_ms, imu).right_angle
    assert rotation_angle_deg(orientation_matrix(found), orientation_matrix(value)) < 1e-6
    assert residual < 0.5


def test_without_an_accelerometer_the_mounting_is_not_guessed(rng):
    mag, t_ms, imu = tumble(np.eye(3), rng, seconds=10.0)
    with pytest.raises(MountingUnobservable, match="no accelerometer"):
        estimate_mounting(mag, t_ms, None)
    with pytest.raises(MountingUnobservable, match="all zero"):
        estimate_mounting(mag, t_ms, ImuSeries(t_ms=imu.t_ms, accel_mss=np.zeros_like(imu.accel_mss)))
    still = ImuSeries(t_ms=imu.t_ms, accel_mss=np.tile([0.0, 0.0, -9.81], (len(imu), 1)))
    with pytest.raises(MountingUnobservable):  # gravity never turns: a unit that was not tumbled
        estimate_mounting(mag[:, [0, 1, 2]] * 0 + [30.0, 0.0, 40.0] + rng.normal(0, 0.3, mag.shape), t_ms, still)


def test_a_real_firmware_s_swept_tumble_states_a_mounting_sigma_that_holds_its_error():
    """ArduCopter SITL's swept unit (FlightAxis peer, docs/firmware.md): the station's record of its tumble, the
    compass calibrated.  SITL's own attitude log puts the compass unturned (0.05°) and 46 ms behind the
    accelerometer.  Twice in the record SITL's clock skipped part of the motion (gravity turned 7° and 18° in one
    reading, against 0.4–0.8° around them); paired across those jerks the estimate found −67.6 ms and 1.05°
    about z and stated 0.10° and ±1.9 ms.  Left out, the rest of the spiral (a spin about z, which a skew and a
    turn about z both fit) states what it knows."""
    record = np.load(Path(__file__).parent / "fixtures" / "ardupilot-sitl-swept-record.npz")
    imu = ImuSeries(t_ms=record["t_acc_ms"], accel_mss=record["accel_mss"].astype(float))
    assert imu.gravity_track().jerks_ms == pytest.approx([10236.0, 10256.0, 21155.0, 21175.0], abs=1.0)
    estimate = estimate_mounting(record["mag_cal"].astype(float), record["t_mag_ms"], imu)
    assert rotation_angle_deg(estimate.data_to_body, np.eye(3)) <= 3.0 * estimate.sigma_deg
    assert abs(estimate.skew_ms + 46.0) <= 3.0 * estimate.own_skew_sigma_ms


def test_a_jump_of_the_board_s_clock_is_not_taken_for_information_on_the_skew(rng):
    """The same spiral made from its formula, sampled and filtered as ArduCopter does (a compass averaging 100 ms,
    an accelerometer through its 20 Hz low-pass): the station says it cannot tell the skew from a turn about z.
    With one jump of the board's clock in the tumble the two filters answer the jump differently, and paired
    across it the estimate stated ±0.06° and was off by 3 to 27 of it.  It must now say what the rest tells:
    that it cannot judge, or a σ that holds the truth (no turn)."""
    for _ in range(4):
        mag, t_ms, imu = averaged_spiral(rng, clock_jump_s=0.43)
        jerks = imu.gravity_track().jerks_ms
        assert len(jerks) >= 1 and np.all(np.abs(jerks - 14000.0) <= 30.0)
        try:
            estimate = estimate_mounting(mag, t_ms, imu)
        except MountingUnobservable:
            continue
        assert rotation_angle_deg(estimate.data_to_body, np.eye(3)) <= 3.0 * estimate.sigma_deg


def test_a_smooth_tumble_has_no_jerk_however_fast_or_noisy(rng):
    """What is left out is a jump, never a fast or noisy motion: the simulators' spiral at full speed (up to
    350°/s), a hand's tumble, and a unit at rest with a noisy accelerometer show none."""
    fast = simulator_fields("tumble", np.arange(0.0, 30.0, 0.02), 1.0, np.array([20.0, 1.5, 42.0]),
                            np.array([0.0, 0.0, -9.80665]))
    assert not len(ImuSeries(t_ms=np.arange(len(fast)) * 20.0, accel_mss=fast + rng.normal(0.0, 0.05, fast.shape))
                   .gravity_track().jerks_ms)
    kept = np.r_[0:700, 706:len(fast)]  # six messages lost: a gap turns gravity no faster
    assert not len(ImuSeries(t_ms=kept * 20.0, accel_mss=fast[kept]).gravity_track().jerks_ms)
    _, _, hand = hand_tumble(np.eye(3), rng)
    assert not len(hand.gravity_track().jerks_ms)
    still = np.array([0.0, 0.0, -9.80665]) + rng.normal(0.0, 0.1, (3000, 3))
    still[1500] = 0.0  # an empty message (INAV's stream has one): no direction, no jerk, no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert not len(ImuSeries(t_ms=np.arange(3000) * 20.0, accel_mss=still).gravity_track().jerks_ms)


def test_two_sensors_four_degrees_apart_in_yaw_are_told_apart(rng):
    a, t_ms, imu = tumble(np.eye(3), rng)
    turned = Rotation.from_euler("Z", 4.0, degrees=True).as_matrix()
    b, _, _ = tumble(turned, np.random.default_rng(1))
    same = heading_agreement(a, t_ms, tumble(np.eye(3), np.random.default_rng(2))[0], t_ms, imu)
    apart = heading_agreement(a, t_ms, b, t_ms, imu)
    assert same.median_deg < 0.5 and same.max_deg < 1.5
    # a 4° turn about the body's Z changes the heading by 4° when level, less or more when tilted
    # (a turn about a tilted axis moves the field's horizontal part by more): the default limits catch it
    assert apart.median_deg > 1.0 and apart.max_deg > 3.0


def gimbal_pair(rng, *, speed: float, lag_s: float, seconds: float = 11.0):
    """Two good, calibrated 10 Hz compasses on the simulators' two-axis gimbal (continuous spin, pitch
    in steps), compass B read ``lag_s`` after compass A, each stamped at its own instant."""
    from magline.sim.truth.imu import compass_pair

    a, t_a, b, t_b, (t_imu, accel) = compass_pair(rng, motion="gimbal", speed=speed, lag_s=lag_s, seconds=seconds)
    return a, t_a, b, t_b, ImuSeries(t_ms=t_imu, accel_mss=accel)


def test_good_compasses_read_at_other_instants_on_a_fast_gimbal_agree(rng):
    """The false reject of issue 28: two good 10 Hz compasses, read a few milliseconds apart on a
    gimbal turning ≈500°/s with pitch steps.  Their readings, paired across 50° of turn (and across a
    step), differed by up to 30°; the largest 1 s window's mean crossed 3°.  Judged by their relation,
    they agree within the noise."""
    worst = max((heading_agreement(*gimbal_pair(rng, speed=speed, lag_s=lag)) for speed in (1.0, 1.3, 1.6, 1.9)
                 for lag in (0.002, 0.005)), key=lambda agreement: agreement.max_deg)
    assert worst.median_deg < 1.0 and worst.max_deg < 3.0
    assert np.allclose(worst.relation, np.eye(3), atol=0.03)


def test_a_turned_compass_is_told_on_a_fast_gimbal_too(rng):
    a, t_a, b, t_b, imu = gimbal_pair(rng, speed=1.6, lag_s=0.005)
    turned = b @ Rotation.from_euler("Z", 3.0, degrees=True).as_matrix().T
    apart = heading_agreement(a, t_a, turned, t_b, imu)
    assert apart.median_deg > 1.0 and apart.max_deg > 3.0
    assert Rotation.from_matrix(apart.relation).as_euler("ZYX", degrees=True)[0] == pytest.approx(3.0, abs=0.5)


def test_a_pair_whose_relative_timing_is_uncertain_is_judged_at_its_best_timing_and_says_what_it_hides(rng):
    """Compass B's stamps 3 ms off its instants: paired there, two good compasses on a fast gimbal read
    2.6–2.8° apart (a false reject).  With its relative timing open by ±4 ms the agreement is taken at the
    timing that agrees best, found within 0.5 ms of the truth; and what the window can hide is said — a
    compass really turned 3° reads less, but never less than 3° together with ``timing_deg``."""
    a, t_a, b, t_b, imu = gimbal_pair(rng, speed=1.9, lag_s=0.005)
    late = np.asarray(t_b, float) + 3.0
    paired = heading_agreement(a, t_a, b, late, imu)
    assert paired.median_deg > 2.0
    opened = heading_agreement(a, t_a, b, late, imu, 4.0)
    assert opened.median_deg < 0.6 and opened.timing_shift_ms == pytest.approx(-3.0, abs=0.5)
    assert opened.paired_median_deg == pytest.approx(paired.median_deg)
    turned = heading_agreement(a, t_a, b @ Rotation.from_euler("Z", 3.0, degrees=True).as_matrix().T, late, imu, 4.0)
    assert turned.median_deg + turned.timing_deg > 3.0


def test_a_reading_between_two_is_taken_along_the_turn():
    """Read every 0.1 s on a unit turning 500°/s, two readings are 50° apart: halfway between them the
    field is 50° from each along the arc (a straight line would be 9 % short)."""
    from magline.core.mounting.agreement import slerp_rows

    turn = Rotation.from_euler("Z", [[0.0], [50.0], [100.0]], degrees=True)
    readings = turn.apply([50.0, 0.0, 0.0])
    halfway = slerp_rows(np.array([50.0, 150.0]), np.array([0.0, 100.0, 200.0]), readings)
    expected = Rotation.from_euler("Z", [[25.0], [75.0]], degrees=True).apply([50.0, 0.0, 0.0])
    assert halfway == pytest.approx(expected, abs=1e-9)
    assert slerp_rows(np.array([-5.0, 250.0]), np.array([0.0, 100.0, 200.0]), readings) == pytest.approx(
        readings[[0, 2]])  # the ends are held


# --------------------------------------------------------------------------- whole units


def ardupilot(tmp_path, faults: str = "", mags: int = 3):
    workdir = tmp_path / "fc"
    workdir.mkdir()
    return create_sim("ardupilot", "tcp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ, workdir=workdir, mag_count=mags,
                      seed=11, boot_time_s=0.3, speed=5.0,
                      faults=SimFaults.parse(faults.split()) if faults else None).start()


def measured(record, name: str):
    return next(m for m in record.measurements if getattr(m, "name", None) == name)


def test_a_good_three_compass_ardupilot_unit_passes_with_every_compass_calibrated(tmp_path, capsys):
    with ardupilot(tmp_path) as sim:
        station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP_OPTIONS)
        record = run_unit(station)
        assert record.verdict is Outcome.PASS, record.cause
        assert sim.prearm_failures() == []  # the firmware's own check: calibrated and consistent
        for suffix in ("", "2", "3"):
            assert f"COMPASS_OFS{suffix}_X" in record.params_read_back
            assert sim.configured(("", "2", "3").index(suffix))
        for prefix in ("", "mag2.", "mag3."):
            assert measured(record, prefix + "orientation").verdict is Verdict.PASS
            sigma = measured(record, prefix + "mounting_sigma_deg").value
            assert measured(record, prefix + "mounting_error_deg").value < Z_NEVER * sigma
            assert abs(measured(record, prefix + "inclination_error_deg").value) < 1.0
        for pair in ("mag1-mag2.", "mag1-mag3.", "mag2-mag3."):
            assert measured(record, pair + "heading_agreement_median_deg").value < 1.0
        # the verdict panel (issue 43): a compact card per compass with its hard iron, then the pairs that
        # agree on one line, and where every row is — an 80×40 terminal keeps the verdict and action in view
        from magline.core.operator_ui.console import verdict_lines

        lines = verdict_lines(record)
        panel = "\n".join(lines)
        # a good pair is flagged only for the station's doubt about its relative timing: two skews of one
        # driver loop differ beyond 3σ by chance in 0.27 % of pairs (a CI run), and are then paired apart,
        # each at its own, within a window that a 1,400°/s tumble turns into more than the 1° limit
        pairs = ("mag1-mag2", "mag1-mag3", "mag2-mag3")
        doubted = [pair for pair in pairs
                   if any(measured(record, f"{pair}.heading_agreement_{figure}_deg").verdict is Verdict.REVIEW
                          for figure in ("median", "max"))]
        assert all(record.unit_info["mounting"][pair]["timing_window_ms"] > 0 for pair in doubted), doubted
        agreeing = " · ".join(pair.replace("-", " and ") for pair in pairs if pair not in doubted)
        order = ["✓ compass 1", "✓ compass 2", "✓ compass 3",
                 *[f"! agreement {pair.replace('-', ' and ')}  REVIEW" for pair in doubted],
                 *([f"✓ agreement  PASS  {agreeing}"] if agreeing else []),
                 f"every measurement: magline show {record.run_id}"]
        assert all(part in panel for part in order), panel
        assert [panel.index(part) for part in order] == sorted(panel.index(part) for part in order)
        assert all(f"compass {n}" in line and "  PASS  hard iron [" in line
                   for n, line in zip((1, 2, 3), (line for line in lines if "✓ compass" in line), strict=True))
        # a flagged pair adds its own card: its title and its two figures with why
        assert "hard_iron_x_ut" not in panel and len(lines) <= 14 + 3 * len(doubted)
        # every sensor's readings and the accelerometer's are kept with the attempt
        engine = create_engine(f"sqlite:///{tmp_path / 'results.sqlite'}")
        with engine.connect() as conn:
            rows = conn.execute(select(attempt_streams).where(attempt_streams.c.run_id == record.run_id)).all()
        engine.dispose()
        streams = {r.stream for r in rows}
        assert {f"mag:{m.device_id}" for m in sim.magnetometers[1:]} | {"imu"} <= streams
        imu = raw_blob.decode_imu(next(r.raw for r in rows if r.stream == "imu"))
        assert np.median(np.linalg.norm(imu.accel_mss, axis=1)) == pytest.approx(9.81, abs=0.2)
        # the unit report draws a residual chart per compass and the mounting table
        from magline.core.reports.commands import write_report

        engine = create_engine(f"sqlite:///{tmp_path / 'results.sqlite'}")
        page = write_report(engine, str(record.run_id), None, tmp_path / "reports").read_text(encoding="utf-8")
        engine.dispose()
        for plot in ('id="residual"', 'id="residual-mag2"', 'id="residual-mag3"'):
            assert plot in page
        assert "Residual — compass 2" in page and "heading agreement" in page
        assert "relation fitted to " in page and " paired readings)" in page
        # samples and coverage for every compass: each one's readings on its ellipsoid and sphere, and in the
        # attempts table its readings and coverage counted as the primary's are
        assert 'id="samples3d-mag2"' in page and 'id="samples3d-mag3"' in page
        accepted = record.attempts[-1]
        for sensor in sim.magnetometers[1:]:
            name = "mag2" if sensor is sim.magnetometers[1] else "mag3"
            assert f"{name}: {len(accepted.more[sensor.device_id])} readings, " in page
        # the export has a column per sensor's measurement and per pair
        from magline.core.cli import main

        capsys.readouterr()
        assert main(["export", "--station", str(station)]) == 0
        import csv
        import io

        header, row = list(csv.reader(io.StringIO(capsys.readouterr().out)))[:2]
        cells = dict(zip(header, row, strict=True))
        assert float(cells["mag3.hard_iron_x_ut"]) == pytest.approx(measured(record, "mag3.hard_iron_x_ut").value)
        assert float(cells["mag2-mag3.heading_agreement_max_deg"]) < 3.0
        assert float(cells["soft_iron_12"]) == pytest.approx(record.calibration["soft_iron"][0][1])  # written matrix
        # the raw export holds every compass's readings, and `magline fit` refits any one of them
        assert main(["export", "--station", str(station), "--raw"]) == 0
        raw_rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
        accepted = record.attempts[-1]
        counts = {name: sum(r["sensor"] == name and r["accepted"] == "1" for r in raw_rows)
                  for name in ("mag1", "mag2", "mag3")}
        assert counts == {"mag1": accepted.samples, "mag2": len(accepted.more[sim.magnetometers[1].device_id]),
                          "mag3": len(accepted.more[sim.magnetometers[2].device_id])}
        export = tmp_path / "raw.csv"
        with export.open("w", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, fieldnames=list(raw_rows[0]))
            writer.writeheader()
            writer.writerows(raw_rows)
        assert main(["fit", str(export), "--sensor", "mag3", "--json", "--field-ut", "48"]) == 0
        refit = json.loads(capsys.readouterr().out)
        assert refit["fitted"].endswith("sensor mag3")
        assert refit["hard_iron_ut"] == pytest.approx(record.calibration["magnetometers"]["mag3"]["hard_iron_ut"],
                                                      abs=0.05)
        assert main(["fit", str(export), "--sensor", "mag7"]) == 2
        assert "no readings of sensor 'mag7' (the file has mag1, mag2, mag3)" in capsys.readouterr().err


def test_calibrating_only_the_primary_of_three_fails_as_the_firmware_does(tmp_path):
    """Reference §16: with only compass 1 written, ArduPilot's prearm says the compasses disagree."""
    with ardupilot(tmp_path) as sim:
        station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP_OPTIONS,
                                {"products": {"AP-QUAD-200": {"magnetometers": [1]}}})
        record = run_unit(station)
        assert record.verdict is Outcome.FAIL
        assert "Compass" in record.cause and next(p.name for p in record.phases if p.outcome == "fail") == "verify"


def test_a_compass_turned_90_degrees_fails_naming_the_fix_and_nothing_is_written(tmp_path):
    with ardupilot(tmp_path, "mag_mounting=2:2") as sim:
        before = sim.read_storage()
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP_OPTIONS))
        assert record.verdict is Outcome.FAIL
        assert "compass 2" in record.cause and "Yaw90" in record.cause
        assert "COMPASS_ORIENT2 = 2" in record.cause and "COMPASS_EXTERN2 = 1" in record.cause
        assert measured(record, "mag2.orientation").value == 2
        assert measured(record, "orientation").verdict is Verdict.PASS
        assert record.params_written == {} and sim.read_storage() == before


def test_orientation_fix_writes_the_orientation_and_proves_it_after_the_power_cycle(tmp_path):
    with ardupilot(tmp_path, "mag_mounting=2:2,3:8") as sim:
        station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP_OPTIONS,
                                {"products": {"AP-QUAD-200": {"orientation": "fix"}}})
        record = run_unit(station)
        assert record.verdict is Outcome.PASS, record.cause
        stored = sim.read_storage()
        assert stored["COMPASS_ORIENT2"] == 2 and stored["COMPASS_EXTERN2"] == 1
        assert stored["COMPASS_ORIENT3"] == 8 and stored["COMPASS_EXTERN3"] == 1
        assert sim.prearm_failures() == []
        # the firmware's own corrected output of every compass now reads the Earth field in body axes
        for i, sensor in enumerate(sim.sets):
            b = sim.body_field_ut(0.0)
            corrected = sim.correct_mg(i, sensor.read_ut(b, np.random.default_rng(0)) * 10.0) / 10.0
            assert np.degrees(np.arccos(corrected @ b / np.linalg.norm(corrected) / np.linalg.norm(b))) < 3.0


def test_a_compass_gone_after_the_power_cycle_fails_naming_it(tmp_path):
    with ardupilot(tmp_path) as sim:
        gone = sim.magnetometers[2].device_id
        sim.faults.mag_missing_after_reboot = gone
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP_OPTIONS))
        assert record.verdict is Outcome.FAIL
        assert f"compass 3 ({gone}) missing after power cycle" in record.cause


def test_two_compasses_that_disagree_by_five_degrees_fail(tmp_path):
    with ardupilot(tmp_path, "mag_yaw_error=2:5") as sim:
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP_OPTIONS))
        assert record.verdict is Outcome.FAIL
        assert measured(record, "mag1-mag2.heading_agreement_median_deg").verdict is Verdict.FAIL
        # within 3σ of the truth: the σ is the estimate's own, its skew against the accelerometer included
        sigma = measured(record, "mag2.mounting_sigma_deg").value
        assert measured(record, "mag2.mounting_error_deg").value == pytest.approx(5.0, abs=Z_NEVER * sigma)
        assert measured(record, "mag1-mag3.heading_agreement_max_deg").verdict is Verdict.PASS


def test_a_listed_compass_the_unit_lacks_fails_naming_it(tmp_path):
    with ardupilot(tmp_path, mags=2) as sim:
        station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP_OPTIONS,
                                {"products": {"AP-QUAD-200": {"magnetometers": [1, 3]}}})
        record = run_unit(station)
        assert record.verdict is Outcome.FAIL
        assert "magnetometer 3 listed for AP-QUAD-200 is not on this unit" in record.cause


def test_a_sensors_own_limit_judges_that_sensor_only(tmp_path):
    with ardupilot(tmp_path, mags=2) as sim:
        station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP_OPTIONS,
                                {"products": {"AP-QUAD-200": {"limits": {"mag2.hard_iron_norm_ut": {"le": 1.0}}}}})
        record = run_unit(station)
        assert record.verdict is Outcome.FAIL
        assert measured(record, "mag2.hard_iron_norm_ut").verdict is Verdict.FAIL
        assert measured(record, "hard_iron_norm_ut").verdict is Verdict.PASS
        assert record.cause.startswith("mag2.hard_iron_norm_ut")


def test_a_two_magnetometer_px4_unit_passes_and_a_turned_external_one_names_cal_mag_rot(tmp_path):
    workdir = tmp_path / "fc"
    workdir.mkdir()
    with create_sim("px4", "udp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ, workdir=workdir, mag_count=2, seed=3,
                    boot_time_s=0.3, speed=5.0) as sim:
        host, port = sim.address.split(":")[1:]
        record = run_unit(write_station("px4-sim.yaml", tmp_path, f"udpout://{host}:{port}", PX4_OPTIONS))
        assert record.verdict is Outcome.PASS, record.cause
        for sensor in sim.magnetometers:
            slot = sim.slot_of(sensor.device_id)
            assert slot is not None and record.params_read_back[f"CAL_MAG{slot}_ID"] == sensor.device_id
        assert measured(record, "mag1-mag2.heading_agreement_median_deg").value < 1.0
        sim.magnetometers[0].mount(2)  # the GPS mast turned 90° on the next unit
        (tmp_path / "b").mkdir()
        record = run_unit(write_station("px4-sim.yaml", tmp_path / "b", f"udpout://{host}:{port}", PX4_OPTIONS))
        assert record.verdict is Outcome.FAIL
        assert "CAL_MAG0_ROT = 2" in record.cause


def test_no_accelerometer_is_an_error_unless_the_product_opts_out(make_station):
    from magline.core.plugins import load_plugins
    from magline.core.sequencer import Sequencer
    from magline.core.station import load_station

    def run(changes):
        path = make_station({"products": {"MOCK-100": changes}})
        seq = Sequencer(load_station(path), load_plugins(), path.parent, sleep=lambda s: None)
        try:
            return seq.run_unit("NO-IMU")
        finally:
            seq.close()

    record = run({"options": {"accelerometer": False}})
    assert record.verdict is Outcome.ERROR
    assert "mounting of magnetometer" in record.cause and "cannot be proven" in record.cause
    assert record.params_written == {}
    skipped = run({"options": {"accelerometer": False}, "orientation": "skip"})
    assert skipped.verdict is Outcome.PASS, skipped.cause
    assert "orientation: skip" in skipped.unit_info["mounting"]


def test_a_mock_unit_mounted_upside_down_fails_naming_the_orientation(make_station):
    from magline.core.plugins import load_plugins
    from magline.core.sequencer import Sequencer
    from magline.core.station import load_station

    path = make_station({"products": {"MOCK-100": {"options": {"misalignment_deg": [180.0, 0.0, 0.0]}}}})
    seq = Sequencer(load_station(path), load_plugins(), path.parent, sleep=lambda s: None)
    try:
        record = seq.run_unit("UPSIDE-DOWN")
    finally:
        seq.close()
    assert record.verdict is Outcome.FAIL
    assert "mounted Roll180 (orientation 8)" in record.cause
    assert "no parameter of this firmware can hold it" in record.cause


def test_a_plugin_judges_the_whole_unit_through_magline_validate_unit(make_station):
    """A third-party check sees every sensor's fit at once; a station fault it raises is an ERROR."""
    from magline.core.faults import StationFault
    from magline.core.measurements import Numeric
    from magline.core.plugins import hookimpl, load_plugins
    from magline.core.sequencer import Sequencer
    from magline.core.station import load_station

    class SpreadOfOffsets:
        def __init__(self) -> None:
            self.seen: dict = {}

        @hookimpl
        def magline_validate_unit(self, run, fits):
            self.seen.update(fits)
            if run.serial == "BROKEN-FIXTURE":
                raise StationFault("the fixture's tilt sensor does not answer")
            return [Numeric(name="offsets_spread_ut", value=float(np.ptp([f.hard_iron_ut[0] for f in fits.values()])))]

    plugin = SpreadOfOffsets()
    path = make_station()
    seq = Sequencer(load_station(path), load_plugins(extra=[plugin]), path.parent, sleep=lambda s: None)
    try:
        good = seq.run_unit("WHOLE-1")
        broken = seq.run_unit("BROKEN-FIXTURE")
    finally:
        seq.close()
    assert good.verdict is Outcome.PASS, good.cause
    assert list(plugin.seen) == [good.unit_info["selected_sensor"]]
    assert measured(good, "offsets_spread_ut").value == 0.0
    assert measured(good, "mounting_error_deg").verdict is Verdict.PASS  # the core's own check still ran
    assert broken.verdict is Outcome.ERROR and "tilt sensor" in broken.cause


def test_misalignment_write_holds_an_external_px4_compass_misalignment_as_custom_euler_angles(tmp_path):
    """PX4 ≥ 1.15 (reference §1): the GPS mast's 2.7° misalignment is written as CAL_MAGn_ROT = 100 with
    ROLL/PITCH/YAW where the product says ``misalignment: write``, proven after the power cycle; the board's
    internal compass cannot hold one (it follows SENS_BOARD_ROT) and the record says so. The firmware's
    corrected output then points where the body field points, and a re-test judges what the custom
    rotation leaves."""
    from scipy.spatial.transform import Rotation

    workdir = tmp_path / "fc"
    workdir.mkdir()
    # sensors at 200 Hz: the 1,500 readings the written estimate is known well from take 7.5 s, not 15
    with create_sim("px4", "udp:127.0.0.1:0", mag_rate_hz=2 * FAST_SENSOR_HZ, workdir=workdir, mag_count=2, seed=5,
                    boot_time_s=0.3, speed=5.0) as sim:
        mast, board = sim.magnetometers
        assert mast.external and not board.external
        mast.mount(0, (1.5, -1.0, 2.0))
        host, port = sim.address.split(":")[1:]
        # a product that writes its misalignment accepts more of it mechanically (the 2.7° mast against 5°:
        # against 3° it stood within the estimate's σ of the limit once the skew is estimated), and its pair
        # limit leaves room for the written estimate's own error — σ ≈ 0.4° with PX4's 8 ms timing jitter on
        # this tumble, up to twice that in heading at 62° inclination (a 1° limit FAILed a good pair at 1.08°)
        # The tumble reads 1,500 readings at the sensor's 100 Hz: the rotation written is the estimate, to be
        # known well (σ ≈ 0.25° against ≈ 0.4° at the 600 a determined stop takes).
        changes = {"products": {"PX4-X500-100": {"misalignment": "write",
                                                 "limits": {"mounting_error_deg": {"le": 5.0},
                                                            "heading_agreement_median_deg": {"le": 2.0}}}},
                   "acquisition": {"stop": "samples", "samples": 1500, "rate_hz": 200.0}}
        record = run_unit(write_station("px4-sim.yaml", tmp_path, f"udpout://{host}:{port}", PX4_OPTIONS, changes))
        assert record.verdict is Outcome.PASS, record.cause
        slot = sim.slot_of(mast.device_id)
        stored = sim.read_storage()
        assert stored[f"CAL_MAG{slot}_ROT"] == 100
        yaw, pitch, roll = mast.rotation.as_euler("ZYX", degrees=True)
        written = [stored[f"CAL_MAG{slot}_{a}"] for a in ("ROLL", "PITCH", "YAW")]
        held = Rotation.from_euler("ZYX", written[::-1], degrees=True)
        sigma = measured(record, "mounting_sigma_deg").value
        assert (held.inv() * mast.rotation).magnitude() < np.radians(Z_NEVER * sigma), (written, [roll, pitch, yaw])
        assert record.params_read_back[f"CAL_MAG{slot}_YAW"] == pytest.approx(written[2])  # proven after the cycle
        error = measured(record, "mounting_error_deg")
        assert error.value == pytest.approx(2.69, abs=Z_NEVER * sigma) and "written as a custom rotation" in error.note
        # the pair is judged as the firmware will hold the mast: what parts the headings is the written
        # estimate's own error, not the 2.7°
        agreement = measured(record, "mag1-mag2.heading_agreement_median_deg").value
        assert agreement < Z_NEVER * sigma * (1.0 + np.tan(np.radians(62.0))), (agreement, sigma)
        internal = measured(record, "mag2.mounting_error_deg")
        assert "not written" in internal.note and "SENS_BOARD_ROT" in internal.note
        board_slot = sim.slot_of(board.device_id)
        assert stored.get(f"CAL_MAG{board_slot}_ROLL", 0.0) == 0.0
        # the firmware's corrected field of the mast compass now has the body field's direction
        rng = np.random.default_rng(0)
        angles = []
        for b in (np.array([30.0, 0.0, 38.0]), np.array([-20.0, 35.0, -25.0]), np.array([0.0, -40.0, 25.0])):
            corrected = sim.corrected_ut(mast, mast.read_ut(b, rng))
            angles.append(np.degrees(np.arccos(corrected @ b / np.linalg.norm(corrected) / np.linalg.norm(b))))
        # the 2.7° misalignment is gone: what is left is the written estimate's error and the reading's
        # noise (0.3 µT on 48 µT, 0.36° on each axis across the field)
        assert max(angles) < Z_NEVER * np.hypot(sigma, np.degrees(0.3 / 48.0)), (angles, sigma)
        # a re-test of the unit: the custom rotation is what the firmware applies, and it leaves little
        (tmp_path / "b").mkdir()
        # (the same product: its pair limit leaves room for the written estimate's error, as above)
        again = run_unit(write_station("px4-sim.yaml", tmp_path / "b", f"udpout://{host}:{port}", PX4_OPTIONS,
                                       changes))
        assert again.verdict is Outcome.PASS, again.cause
        # what is left is the written estimate's error and this one's: their σ combined
        combined = np.hypot(sigma, measured(again, "mounting_sigma_deg").value)
        assert measured(again, "mounting_error_deg").value < Z_NEVER * combined
        assert measured(again, "orientation").value == 0


def test_a_compass_read_by_a_slower_loop_is_no_false_reject_and_the_unproven_agreement_is_flagged(tmp_path):
    """A real board's third compass often reaches its stream older than the others (another bus,
    another driver loop): here 100 ms of firmware time, 20 ms on the wire at speed 5.  The station
    finds each compass's skew; paired at two skews known to ±0.4 ms each, good compasses turning at
    1,400°/s read 2° apart and the unit FAILed.  Now each such pair is judged at the relative timing
    within 3σ that agrees best: the unit passes, and an agreement that timing alone could hide is
    flagged for review with how much, in words."""
    with ardupilot(tmp_path, "mag_latency=3:100") as sim:
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP_OPTIONS,
                                        {"acquisition": {"samples": 300}}))
    assert record.verdict is Outcome.PASS, record.cause
    # one loop: paired at one skew — unless the two estimates of it differ beyond 3σ, as 0.27 % of such pairs do
    skews = [(measured(record, p + "time_skew_ms").value, measured(record, p + "time_skew_sigma_ms").value)
             for p in ("", "mag2.")]
    apart = bool(abs(skews[0][0] - skews[1][0]) > 3.0 * np.hypot(skews[0][1], skews[1][1]))
    assert (record.unit_info["mounting"]["mag1-mag2"]["timing_window_ms"] > 0.0) is apart
    for first in ("mag1", "mag2"):
        prefix = "" if first == "mag1" else "mag2."
        lag = measured(record, prefix + "time_skew_ms").value - measured(record, "mag3.time_skew_ms").value
        sigma = np.hypot(measured(record, prefix + "time_skew_sigma_ms").value,
                         measured(record, "mag3.time_skew_sigma_ms").value)
        assert lag == pytest.approx(100.0 / 5.0, abs=Z_NEVER * sigma)
        pair = record.unit_info["mounting"][f"{first}-mag3"]
        assert pair["timing_window_ms"] > 0.0 and abs(pair["timing_shift_ms"]) <= pair["timing_window_ms"]
        median = measured(record, f"{first}-mag3.heading_agreement_median_deg")
        assert median.value < 1.0
        if median.value + pair["timing_deg"] > median.high:
            assert median.verdict is Verdict.REVIEW and f"{pair['timing_deg']:.1f}°" in median.note
        else:
            assert median.verdict is Verdict.PASS


@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
def test_each_compass_is_paired_at_the_instant_it_was_read_whatever_the_firmwares_skew(tmp_path, flavour):
    """Issue 50: PX4 streams a sensor_mag 28–36 ms older than the SCALED_IMU time it travels with; on
    ArduCopter a compass reading belongs ≈ 40 ms after the RAW_IMU it first appears in.  The simulators
    stream both (compressed with the motion's speed, so at speed 5 a 6–8 ms skew turns the unit by the
    ≈ 10° a real skew does), and paired at their stamps a good compass read ≈ 10° of mounting error.  The
    station finds each compass's skew with its sign, records it, pairs the compasses with it, and the
    good unit passes with its mounting within its σ of true (``Z_NEVER``)."""
    workdir = tmp_path / "fc"
    workdir.mkdir()
    listen = "udp:127.0.0.1:0" if flavour == "px4" else "tcp:127.0.0.1:0"
    with create_sim(flavour, listen, mag_rate_hz=FAST_SENSOR_HZ, workdir=workdir, mag_count=2, seed=7,
                    boot_time_s=0.3, speed=5.0) as sim:
        host, port = sim.address.split(":")[1:]
        address = f"udpout://{host}:{port}" if flavour == "px4" else sim.address
        options = PX4_OPTIONS if flavour == "px4" else AP_OPTIONS
        record = run_unit(write_station(f"{flavour}-sim.yaml", tmp_path, address, options))
        skew_ms = (-1000.0 * np.mean(sim.MAG_AGE_S) if flavour == "px4" else 1000.0 * sim.ACCEL_AGE_S) / sim.speed
    assert record.verdict is Outcome.PASS, record.cause
    for prefix in ("", "mag2."):
        skew = measured(record, prefix + "time_skew_ms").value
        sigma = measured(record, prefix + "time_skew_sigma_ms").value
        assert np.sign(skew) == np.sign(skew_ms) and abs(skew - skew_ms) < Z_NEVER * sigma, (skew, sigma, skew_ms)
        mounting = measured(record, prefix + "mounting_error_deg").value
        assert mounting < Z_NEVER * measured(record, prefix + "mounting_sigma_deg").value
    assert measured(record, "mag1-mag2.heading_agreement_median_deg").value < 0.5
    assert record.unit_info["mounting"]["mag1"]["skew_ms"] == pytest.approx(measured(record, "time_skew_ms").value,
                                                                               abs=0.01)


def turntable_tumble(mounted: np.ndarray, tilts: tuple[tuple[float, float], ...]) -> tuple[np.ndarray, np.ndarray,
                                                                                        ImuSeries]:
    """A turntable's tumble: the table turning at 90 °/s while the cradle is held at each (roll, pitch) tilt in
    turn, 50 Hz readings of a sensor mounted as ``mounted`` and of the accelerometer, at one instant each,
    without noise."""
    from magline.sim.truth.sensor import earth_field_ned

    t = np.arange(0.0, 8.0 * len(tilts), 0.02)
    held = np.repeat(np.array(tilts, float), len(t) // len(tilts), axis=0)
    poses = Rotation.from_euler("z", 90.0 * t[:, None], degrees=True) * Rotation.from_euler("xy", held, degrees=True)
    body = poses.inv().apply(earth_field_ned(48.0, 62.0))
    accel = poses.inv().apply([0.0, 0.0, -9.80665])
    return body @ np.asarray(mounted), t * 1000.0, ImuSeries(t_ms=t * 1000.0, accel_mss=accel)


@pytest.mark.parametrize(("mounted", "value"), [(np.eye(3), 0), (np.diag([1.0, -1.0, -1.0]), 8)],
                         ids=["straight", "Roll180"])
def test_gravity_seen_in_one_plane_is_decided_by_the_place_s_dip_not_by_noise(mounted, value):
    """A turntable whose cradle was tilted about one axis only (level, on its sides, upside down) shows
    gravity in one plane; then a sensor mounted straight and one mounted Roll180 give the same readings,
    each with the field dipping the other way — a CI run FAILed two good units as Roll180 with the
    inclination 124° off.  The place's dip (the field source's) decides; without it the tumble cannot
    prove the mounting and says so; tilted about the other axis too, the readings decide by themselves."""
    rolls = ((0.0, 0.0), (90.0, 0.0), (180.0, 0.0), (-90.0, 0.0))
    mag, t, imu = turntable_tumble(mounted, rolls)
    estimate = estimate_mounting(mag, t, imu, dip_deg=62.0)
    found, error_deg = estimate.right_angle_of(estimate.data_to_body)
    assert found == value and error_deg < 0.1 and estimate.inclination_deg == pytest.approx(62.0, abs=0.1)
    with pytest.raises(MountingUnobservable, match="about one axis only"):
        estimate_mounting(mag, t, imu)
    mag, t, imu = turntable_tumble(mounted, (*rolls, (0.0, 45.0)))
    estimate = estimate_mounting(mag, t, imu)
    assert estimate.right_angle_of(estimate.data_to_body)[0] == value
    assert estimate.inclination_deg == pytest.approx(62.0, abs=0.1)
