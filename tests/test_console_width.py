"""Every sentence of the verdict panel is whole on any terminal from 60 columns up (issue 30): the
panel wraps its lines instead of the console cropping them at the edge."""

from __future__ import annotations

import io
import re

import pytest
from rich.console import Console

from magline.core.measurements import Numeric, Verdict
from magline.core.operator_ui.console import verdict_panel
from magline.core.record import Outcome
from magline.testing import make_record

SENTENCES = [
    "only 310 of 600 readings within 60 s: the sensor delivers about 10 readings/s; the stream carried each about "
    "5 times, so 600 readings take about 60 s — raise acquisition.timeout_s or lower acquisition.samples",
    "the unit now holds a new, unverified calibration (10 parameters: COMPASS_OFS_X, COMPASS_OFS_Y, COMPASS_OFS_Z, "
    "COMPASS_DIA_X); re-test the unit",
    "no process review: 0 passing MOCK-100 units on line DEMO in the store, 30 needed",
]


def rendered(width: int) -> str:
    record = make_record("SN-WIDE", verdict=Outcome.ERROR, cause=f"{SENTENCES[0]} — {SENTENCES[1]}",
                         review_note=SENTENCES[2], store="/var/lib/magline/a-rather-long-path/results.sqlite run 17",
                         measurements=[Numeric(name="mag2.heading_agreement_median_deg", value=0.4, unit="°", high=1.0,
                                               verdict=Verdict.PASS)])
    out = io.StringIO()
    console = Console(file=out, width=width, soft_wrap=True, color_system=None)  # as the station builds it
    console.print(verdict_panel(record, "ERROR", "magenta"), soft_wrap=False)
    return out.getvalue()


@pytest.mark.parametrize("width", [60, 80, 250])
def test_every_sentence_is_whole_at_any_width(width):
    text = rendered(width)
    assert all(len(line) <= width for line in text.splitlines())
    inside = " ".join(re.sub(r"^[│╭╰]\s?|\s?[│╮╯]$", "", line).strip() for line in text.splitlines())
    flowing = re.sub(r"\s+", " ", inside)
    for sentence in SENTENCES:
        assert sentence in flowing.replace("- ", "-") or sentence in flowing, (width, sentence)


def test_the_help_speaks_plainly(capsys):
    from magline.core.cli import main

    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "``" not in out and "Calibrate drone magnetometers" in out


def test_a_simulator_s_help_gives_each_fault_s_value_in_the_form_it_takes(capsys):
    """A fault's value is shown as it is typed (``mag_mounting=N:K,…``: compass N mounted in firmware
    orientation K), and what the help shows parses: a form that said ``A,B`` sent a reader astray."""
    from magline.core.cli import main
    from magline.sim.faults import SimFaults

    with pytest.raises(SystemExit):
        main(["sim", "px4", "--help"])
    help_text = re.sub(r"\s+", " ", capsys.readouterr().out)
    for shown in ("mag_mounting=N:K,…", "mag_yaw_error=N:DEG,…", "mag_latency=N:MS,…", "link_stalls=HOLD_S:EVERY_S",
                  "mag_warmup=UT:TAU_S", "cal_applied=sign|unit|slot|none", "current_sensor=none|bypassed"):
        assert shown in help_text, shown
    faults = SimFaults.parse(["mag_mounting=1:2,2:8", "mag_yaw_error=2:4.5", "mag_warmup=3:2", "link_stalls=0.3:2"])
    assert faults.mountings() == {0: (2, 0.0), 1: (8, 4.5)} and faults.link_stalls == "0.3:2"


@pytest.mark.parametrize(("board", "own", "others"), [
    ("px4", ["cal_applied=sign|unit|slot|none", "no_factory_partition", "motor_test_refused"],
     ["msp_variant", "uid_changes_at_reboot"]),
    ("ardupilot", ["motor_test_refused", "current_sensor=none|bypassed", "mag_mounting=N:K,…"],
     ["cal_applied", "msp_variant", "factory_store_fails"]),
    ("inav", ["msp_variant=VARIANT", "armed", "mag_mounting=N:K,…", "link_stalls=HOLD_S:EVERY_S"],
     ["cal_applied", "motor_test_refused", "ignore_param_set", "mag_yaw_error"])])
def test_each_simulator_s_help_lists_its_own_faults_and_it_refuses_another_board_s(capsys, board, own, others):
    """``sim px4 --help`` listed INAV's ``msp_variant`` and ``armed``: each simulator lists the faults it has,
    and one it has not is refused in one line naming those it has (it did nothing, silently)."""
    from magline.core.cli import main

    with pytest.raises(SystemExit):
        main(["sim", board, "--help"])
    faults = re.sub(r"\s+", " ", capsys.readouterr().out).split("inject a fault", 1)[1].split(" --", 1)[0]
    assert all(name in faults for name in own), faults
    assert not any(re.search(rf"\b{name}\b", faults) for name in others), faults
    assert main(["sim", board, "--listen", "tcp:127.0.0.1:0", "--fault", others[0]]) == 2
    said = capsys.readouterr().err.strip().splitlines()
    assert len(said) == 1 and f"{board}'s simulator has no fault {others[0]!r} (" in said[0]
    assert own[1].split("=")[0] in said[0]  # naming the faults it has


def test_a_slot_panel_drops_a_wait_when_it_ends_and_keeps_a_prompt():
    """The slot board shows a wait's count in the slot's panel until the wait says it ended (a gimbal
    station prompts nobody, so nothing else would replace it); readings do not end a wait, and the
    end of a wait leaves a prompt the operator has been given since."""
    from types import SimpleNamespace

    from magline.core.operator_ui.console_slots import SlotBoard

    board = SlotBoard(Console(file=io.StringIO(), width=80), live=False)
    run = SimpleNamespace(slot="A", serial="SN-A1", part="PX4-FMU")
    board.phase_started(run, "acquire")
    board.waiting(run, "warming up before the tumble", 3.0, 20.0)
    assert board.views["A"].message == "warming up before the tumble (3 s, 17 s left)"
    board.progress(run, 1, 12, 0.1, 0.5)
    assert board.views["A"].message.startswith("warming up")
    board.wait_ended(run)
    assert board.views["A"].message == ""
    board.prompt(run, "Tumble the unit")
    board.wait_ended(run)
    board.progress(run, 1, 40, 0.2, 0.5)
    assert board.views["A"].message == "Tumble the unit"


class _Terminal(io.StringIO):
    """What a station's console writes to at an 80-column terminal."""

    def isatty(self) -> bool:
        return True


def test_console_lines_wrap_at_words_on_a_terminal_and_stay_whole_in_a_pipe(monkeypatch):
    """At an 80-column terminal the turntable's cradle lines and the last line of an ERROR wrapped where the
    edge fell, mid-word: on a terminal they wrap at words; piped (a log, a service) a line stays one line."""
    from magline.core.operator_ui.console import OperatorConsole

    sentence = ("cradle 2: nose down 90° — pitch the cradle until its nose points at the floor, roll level "
                "(still to face the floor: left side, nose, right side)")
    monkeypatch.setenv("COLUMNS", "80")
    for stream, terminal in ((_Terminal(), True), (io.StringIO(), False)):
        monkeypatch.setattr("sys.stdout", stream)
        OperatorConsole().note(sentence)
        lines = stream.getvalue().splitlines()
        if terminal:
            assert len(lines) > 1 and all(len(line) <= 80 for line in lines)
            assert " ".join(lines).split() == sentence.split()  # every word whole
        else:
            assert lines == [sentence]


def test_a_command_s_error_wraps_at_words_on_a_terminal(monkeypatch, capsys):
    from magline.core.text import for_terminal

    message = ("magline: station file stations/x.yaml: products.AP-QUAD-200.connection (line 14): "
               "tcp:127.0.0.1:99999 is not an address — give tcp:HOST:PORT with a port from 1 to 65535")
    monkeypatch.setenv("COLUMNS", "80")
    wrapped = for_terminal(message, _Terminal())
    assert all(len(line) <= 80 for line in wrapped.splitlines()) and wrapped.split() == message.split()
    assert for_terminal(message, io.StringIO()) == message
