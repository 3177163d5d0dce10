"""The ArduCopter SITL runner's own parts (``magline.sitl.ardupilot_run``), without the firmware: the truth it
sets in SITL's parameters is what a right calibration writes as ArduPilot applies it, and the field it holds
the station to is the firmware's table at SITL's home."""

from __future__ import annotations

import numpy as np
import pytest

from magline.sitl.ardupilot_run import COMPASSES, ApTruth, table_field


def ardupilot_matrix(diagonal, off_diagonal) -> np.ndarray:
    """COMPASS_DIA/ODI (or SIM_MAGn_DIA/ODI) as one symmetric matrix: ODI holds xy, xz, yz."""
    (dx, dy, dz), (oxy, oxz, oyz) = diagonal, off_diagonal
    return np.array([[dx, oxy, oxz], [oxy, dy, oyz], [oxz, oyz, dz]])


@pytest.mark.parametrize("compass", range(COMPASSES))
def test_the_parameters_the_truth_expects_give_the_firmware_the_field_back(compass):
    """SITL reads ``M_sim⁻¹·B − OFS_sim``; ArduPilot calibrates ``M·(raw + OFS)``: with the expected
    COMPASS_* that is the field itself, whatever its direction."""
    truth = ApTruth.drawn(7)
    sim = truth.sim_params()
    n = compass + 1
    m_sim = ardupilot_matrix([sim[f"SIM_MAG{n}_DIA_{a}"] for a in "XYZ"], [sim[f"SIM_MAG{n}_ODI_{a}"] for a in "XYZ"])
    ofs_sim = np.array([sim[f"SIM_MAG{n}_OFS_{a}"] for a in "XYZ"])
    field = np.random.default_rng(compass).normal(size=3) * 300.0  # mG
    raw = np.linalg.solve(m_sim, field) - ofs_sim
    want = truth.expected()
    suffix = "" if compass == 0 else str(n)
    m = ardupilot_matrix([want[f"COMPASS_DIA{suffix}_{a}"] for a in "XYZ"],
                         [want[f"COMPASS_ODI{suffix}_{a}"] for a in "XYZ"])
    ofs = np.array([want[f"COMPASS_OFS{suffix}_{a}"] for a in "XYZ"])
    assert m @ (raw + ofs) == pytest.approx(field)
    assert sim[f"SIM_MAG{n}_ORIENT"] == 0.0


def test_a_turned_compass_is_set_in_the_simulator_alone():
    truth = ApTruth.drawn(7, turned={1: 2})
    assert truth.sim_params()["SIM_MAG2_ORIENT"] == 2.0 and truth.sim_params()["SIM_MAG1_ORIENT"] == 0.0
    assert not any(k.startswith("COMPASS_ORIENT") for k in truth.expected())


def test_the_field_is_read_from_the_firmware_s_table_at_a_grid_point(tmp_path):
    """``tables.cpp`` holds declination, inclination and intensity (gauss) on a 10° grid from −90° latitude
    and −180° longitude; at a grid point the firmware's interpolation is the table's value itself."""
    def rows(value: float) -> str:
        return ",\n".join("    {" + ",".join(f"{value + lat * 0.001 + lon * 1e-5:.5f}f" for lon in range(37)) + "}"
                          for lat in range(19))

    table = tmp_path / "libraries" / "AP_Declination" / "tables.cpp"
    table.parent.mkdir(parents=True)
    table.write_text("\n".join(
        f"const float AP_Declination::{name}[LAT_TABLE_SIZE][LON_TABLE_SIZE] = {{\n{rows(value)}\n}};\n"
        for name, value in (("declination_table", 1.0), ("inclination_table", 60.0), ("intensity_table", 0.4))))
    field_ut, inclination = table_field(tmp_path, 50.0, 10.0)  # row 14, column 19
    assert field_ut == pytest.approx((0.4 + 14 * 0.001 + 19 * 1e-5) * 100.0)
    assert inclination == pytest.approx(60.0 + 14 * 0.001 + 19 * 1e-5)


@pytest.mark.parametrize("compass", range(COMPASSES))
def test_the_compensation_the_truth_expects_cancels_the_simulated_current_s_field(compass):
    """SITL adds ``SIM_MAG_MOT · I`` to the body field before each compass's distortion; ArduPilot adds
    ``COMPASS_MOTn · I`` after its calibration (``correct_field``): with the expected COMPASS_MOTn and the
    expected calibration the firmware's field is the field without the current, at any current."""
    truth = ApTruth.drawn(7, mag_mot_mg_per_a=[1.2, -0.7, 0.4])
    sim, want = truth.sim_params(), {**truth.expected(), **truth.expected_compensation()}
    n, suffix = compass + 1, "" if compass == 0 else str(compass + 1)
    m_sim = ardupilot_matrix([sim[f"SIM_MAG{n}_DIA_{a}"] for a in "XYZ"], [sim[f"SIM_MAG{n}_ODI_{a}"] for a in "XYZ"])
    ofs_sim = np.array([sim[f"SIM_MAG{n}_OFS_{a}"] for a in "XYZ"])
    mot_sim = np.array([sim[f"SIM_MAG_MOT_{a}"] for a in "XYZ"])
    m = ardupilot_matrix([want[f"COMPASS_DIA{suffix}_{a}"] for a in "XYZ"],
                         [want[f"COMPASS_ODI{suffix}_{a}"] for a in "XYZ"])
    ofs = np.array([want[f"COMPASS_OFS{suffix}_{a}"] for a in "XYZ"])
    mot = np.array([want[f"COMPASS_MOT{suffix}_{a}"] for a in "XYZ"])
    field = np.array([180.0, -40.0, 420.0])  # mG
    for amps in (0.0, 20.0, 40.0):
        raw = np.linalg.solve(m_sim, field + mot_sim * amps) - ofs_sim
        assert m @ (raw + ofs) + mot * amps == pytest.approx(field)
    assert want["COMPASS_MOTCT"] == 2.0


def test_a_runner_runs_only_the_units_asked_for_and_names_what_it_has(tmp_path, capsys):
    """``--unit`` picks units of the tier; one the runner does not have is refused in one line, nothing run."""
    from magline.sitl.checks import Check, runner_parser, summarise

    ran = []

    def unit(label: str):
        def run(folder):
            ran.append(label)
            return {"unit_info": {"firmware": "4.7.0"}}, [Check(f"{label} check", "x", "y", True)]
        return run

    units = {name: unit(name) for name in ("good", "turned", "swept")}
    args = runner_parser("m", "doc", "--source", "tree").parse_args(["--source", "x", "--unit", "swept"])
    assert summarise("t", tmp_path, units, None, args.unit) == 0
    assert ran == ["swept"] and "[swept] ok" in capsys.readouterr().out
    assert summarise("t", tmp_path, units, None, ["sweep"]) == 2
    assert ran == ["swept"]
    assert capsys.readouterr().err.strip() == "no unit sweep in this runner: it has good, turned, swept"
