"""`magline fit`: JSON shape, readable summary, refusals and CSV errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from simstation import attempt_rows

from magline.core.cli import main
from magline.core.fit.samples_csv import RawSamples, format_samples
from magline.sim.truth import earth_field_ned, motion_directions, random_truth


def write_csv(path, motion="hand_tumble", seed=3):
    rng = np.random.default_rng(seed)
    truth = random_truth(rng)
    d = motion_directions(motion, 600, rng, earth_field_ned(48.0, 62.0))
    m = truth.read(d * 48.0, rng)
    path.write_text(format_samples(RawSamples(mag_ut=m, t_ms=np.arange(600) * 20.0)), encoding="utf-8")
    return truth


def test_fit_json_document(tmp_path, capsys):
    truth = write_csv(tmp_path / "raw.csv")
    assert main(["fit", str(tmp_path / "raw.csv"), "--json", "--field-ut", "48"]) == 0
    doc = json.loads(capsys.readouterr().out)
    for key in ("hard_iron_ut", "soft_iron", "field_ut", "residual_ut", "coverage", "samples",
                "hard_iron_sigma_ut", "field_sigma_ut", "raw_to_reference_ratio"):
        assert key in doc
    h, s = np.array(doc["hard_iron_ut"]), np.array(doc["soft_iron"])
    assert s.shape == (3, 3) and np.allclose(s, s.T)
    assert doc["samples"]["total"] == 600 and doc["samples"]["used"] <= 600
    assert np.all(np.abs(h - truth.hard_iron_ut) < 5 * np.array(doc["hard_iron_sigma_ut"]))
    # the contract: soft_iron @ (m − hard_iron_ut) lies on a sphere of field_ut
    raw = np.loadtxt(tmp_path / "raw.csv", delimiter=",", skiprows=1)[:, :3]
    radius = np.linalg.norm((raw - h) @ s.T, axis=1)
    assert abs(radius.mean() - doc["field_ut"]) < 0.1


def test_fit_summary_is_readable(tmp_path, capsys):
    write_csv(tmp_path / "raw.csv")
    assert main(["fit", str(tmp_path / "raw.csv"), "--model", "full"]) == 0
    out = capsys.readouterr().out
    assert "hard iron" in out and "µT" in out and "full" in out
    assert "warm-up      no drift (statistic" in out  # the readings carry time: the drift test's decision
    assert "µT would not show)" in out  # and how large a drift could have passed it unseen


def test_fit_summary_says_when_the_drift_could_not_be_judged(tmp_path, capsys):
    """On half a sweep of the simulators' even tumble a drift is a soft-iron change: said, not hidden."""
    from magline.sim.truth.imu import simulator_fields

    rng = np.random.default_rng(sum(map(ord, "drift not judged summary")))
    t = 1.0 + np.arange(300) / 50.0
    m = random_truth(rng).read(simulator_fields("tumble", t, 1.0, earth_field_ned(48.0, 63.0)), rng)
    (tmp_path / "half.csv").write_text(format_samples(RawSamples(mag_ut=m, t_ms=t * 1000.0)), encoding="utf-8")
    assert main(["fit", str(tmp_path / "half.csv"), "--field-ut", "48"]) == 0
    out = capsys.readouterr().out
    assert "warm-up      not judged: these readings cannot tell an offset drift from soft iron" in out


def test_fit_refuses_single_axis_with_advice(tmp_path, capsys):
    write_csv(tmp_path / "raw.csv", motion="single_axis")
    assert main(["fit", str(tmp_path / "raw.csv"), "--json"]) == 1
    captured = capsys.readouterr()
    assert "rotate" in captured.err
    assert json.loads(captured.out)["refused"] in {"single_plane", "undetermined"}


@pytest.mark.parametrize(("content", "expected"), [
    ("", "empty file"),
    ("mag_x_ut,mag_y_ut\n1,2\n", "missing column(s) mag_z_ut"),
    ("mag_x_ut,mag_y_ut,mag_z_ut\n1,2,3\n1,abc,3\n", ":3: column mag_y_ut: 'abc' is not a number"),
    ("mag_x_ut,mag_y_ut,mag_z_ut\n1,2,nan\n", ":2: column mag_z_ut: 'nan' is not a finite number"),
    ("mag_x_ut,mag_y_ut,mag_z_ut\n", "no samples"),
])
def test_csv_errors_are_clear(tmp_path, capsys, content, expected):
    path = tmp_path / "bad.csv"
    path.write_text(content, encoding="utf-8")
    assert main(["fit", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and expected in err


@pytest.mark.parametrize(("option", "said"), [
    (["--field-ut", "-5"], "argument --field-ut: -5 is not above 0"),  # was NumPy's LinAlgError
    (["--field-ut", "0"], "argument --field-ut: 0 is not above 0"),  # was a ZeroDivisionError
    (["--bins", "0"], "argument --bins: 0 is not between 4 and 10000"),  # was a ValueError's traceback
    (["--range-ut", "-1"], "argument --range-ut: -1 is not above 0"),  # was "only 0 usable samples"
    (["--gain-sigma", "-1"], "argument --gain-sigma: -1 is not above 0 and at most 1"),
])
def test_a_setting_no_fit_can_take_is_refused_by_its_option_not_a_traceback(tmp_path, capsys, option, said):
    write_csv(tmp_path / "raw.csv")
    with pytest.raises(SystemExit) as refused:
        main(["fit", str(tmp_path / "raw.csv"), *option])
    out, err = capsys.readouterr()
    assert refused.value.code == 2 and out == "" and said in err and "Traceback" not in err


def test_missing_file(tmp_path, capsys):
    assert main(["fit", str(tmp_path / "nope.csv")]) == 2
    assert "cannot read" in capsys.readouterr().err


def test_diagonal_model_on_rotated_soft_iron_warns_instead_of_blaming_the_operator(tmp_path, capsys):
    """An autopilot that holds only a diagonal still gets its best diagonal fit; the summary says
    why it is poor (the board's soft iron is rotated), not "rotate more"."""
    write_csv(tmp_path / "raw.csv", seed=4)  # random_truth rotates the soft-iron axes
    assert main(["fit", str(tmp_path / "raw.csv"), "--model", "diagonal"]) == 0
    out = capsys.readouterr().out
    assert "not axis-aligned" in out and "--model full" in out
    assert main(["fit", str(tmp_path / "raw.csv"), "--model", "full"]) == 0
    assert "not axis-aligned" not in capsys.readouterr().out


def test_fit_on_an_export_fits_one_run_and_says_which(make_station, tmp_path, capsys):
    """Issue 31: an export holds every run and every attempt; pooled, two units fit no ellipsoid."""
    station = make_station()
    for serial in ("E-1", "E-2"):
        assert main(["run", str(station), "--serial", serial]) == 0
    export = tmp_path / "export.csv"
    capsys.readouterr()
    assert main(["export", "--station", str(station), "--raw"]) == 0
    export.write_text(capsys.readouterr().out, encoding="utf-8")

    assert main(["fit", str(export)]) == 2
    err = capsys.readouterr().err
    assert "2 runs in the file — choose one with --run UUID" in err and "E-1 attempt 2" in err
    assert main(["fit", str(export), "--serial", "E-2", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["fitted"].endswith("serial E-2 attempt 2 sensor mag1")  # the primary by default
    accepted = [a for a in attempt_rows(tmp_path / "magline-demo-results.sqlite", "E-2") if a["accepted"]]
    assert doc["samples"]["total"] == accepted[0]["samples"]  # the accepted attempt only, not both
    assert doc["field_from"].startswith("the readings' own radius")
    assert main(["fit", str(export), "--serial", "E-2", "--attempt", "1"]) == 1  # the refused single-axis spin
    assert "calibration refused" in capsys.readouterr().err
