"""Faults the simulator can inject, switchable from the command line and from tests.

Each is something a real line has seen: a lossy link, a write the firmware ignores, storage
that does not keep a value, a board that boots slowly or not at all, a link that dies in the
middle of an acquisition, a sensor gone after reboot, a second sensor enumerated first, compass
offsets that settle while the board warms after power-on.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from functools import lru_cache

MAVLINK = ("px4", "ardupilot")  # faults of the MAVLink boards' parameter, command and battery handling


@dataclass
class SimFaults:
    drop_percent: float = 0.0  # each outgoing frame is lost with this probability (%)
    # names ("*" = all) whose PARAM_SET is dropped
    ignore_param_set: list[str] = field(default_factory=list, metadata={"boards": MAVLINK})
    # names whose PARAM_SET takes but its echo is lost
    lose_param_echo: list[str] = field(default_factory=list, metadata={"boards": MAVLINK})
    # names this firmware does not have (an older release): reads and writes of them go unanswered, as
    # ArduPilot and PX4 v1.13–v1.16 treat unknown names
    unknown_params: list[str] = field(default_factory=list, metadata={"boards": MAVLINK})
    # "NAME:K": the answers to the first K reads of NAME are lost on the way (a lossy link, answers late)
    lose_param_answers: list[str] = field(default_factory=list, metadata={"boards": MAVLINK, "form": "NAME:K,…"})
    # "COMMAND:K": the acknowledgements of the first K COMMAND_LONGs of this number are lost on the way (the board
    # carries the commands out; a lossy link, or a host so loaded that the answers come after the station's wait)
    lose_command_acks: list[str] = field(default_factory=list, metadata={"boards": MAVLINK, "form": "COMMAND:K,…"})
    # the link goes silent when a PARAM_SET of this name arrives (a cable pulled)
    link_loss_at_param_set: str = field(default="", metadata={"boards": MAVLINK})
    no_persist: list[str] = field(default_factory=list)  # names whose value never reaches storage
    reboot_fails: bool = False  # after a reboot the board never comes back
    # while the unit rests after a power cycle every compass reads the same value each time (a quiet sensor
    # whose steps are coarser than its noise, or a SITL whose compass has no noise): no new distinct reading;
    # held still for a current sweep, a compass reads without noise: a new value only when the current changes
    quiet_at_rest: bool = False
    # every compass repeats the reading it had this long after a mag stream starts, ever after (a sensor whose
    # bus hung: the driver publishes its last sample again and again) while the messages keep coming
    mag_stuck_after_s: float | None = field(default=None, metadata={"boards": MAVLINK})
    # the reboot command's ACK (INAV: MSP_REBOOT's reply) is lost on the way (the board reboots all the same)
    lose_reboot_ack: bool = False
    link_loss_after_s: float | None = None  # the link goes silent this long after a mag stream starts
    # "HOLD_S:EVERY_S": every EVERY_S the board's output is held HOLD_S, then leaves at once — what a station
    # sees of a host that reads its port late (a busy PC) or a USB bus that stalls: bytes late by up to
    # HOLD_S, in bursts, none lost, their stamps unchanged
    link_stalls: str = field(default="", metadata={"form": "HOLD_S:EVERY_S"})
    mag_missing_after_reboot: int | None = None  # device id that is not detected on the next boot
    # the second sensor enumerates first on the next boot
    swap_mags_after_reboot: bool = field(default=False, metadata={"boards": MAVLINK})
    # "N:K": magnetometer N (1, 2, 3 in detection order) is mounted in firmware orientation K
    # (2 = Yaw90, 8 = Roll180) while the firmware's parameters still say it is not rotated
    mag_mounting: list[str] = field(default_factory=list, metadata={"form": "N:K,…"})
    # "N:DEG": magnetometer N is turned DEG degrees about the body's Z axis (two compasses disagree)
    mag_yaw_error: list[str] = field(default_factory=list, metadata={"boards": MAVLINK, "form": "N:DEG,…"})
    # "N:MS": magnetometer N's readings reach its stream MS ms (firmware time) older than the other
    # compasses' — a compass on a slower bus or read by a slower driver loop, as a second compass of a
    # real board often is: each stream carries its own compass's latest reading at the message's time
    mag_latency: list[str] = field(default_factory=list, metadata={"boards": MAVLINK, "form": "N:MS,…"})
    # the board's current sensor reads this many % off (−20: 20 % low, a power module's wrong scale)
    current_sensor_pct: float = field(default=0.0, metadata={"boards": MAVLINK})
    # the board's battery monitor: "none" measures no current (a voltage-only monitor: BATTERY_STATUS and
    # SYS_STATUS say "not measured", ArduPilot's −1 cA, PX4's −1 A), "bypassed" measures a path the sweep's
    # current does not flow through (the wrong monitor primary, the load upstream of it): the board's own
    # draw only, while the compasses see the whole current
    current_sensor: str = field(default="", metadata={"boards": MAVLINK, "form": "none|bypassed"})
    # µT a magnetised part keeps adding at every compass (along its interference) once a current has flowed
    interference_remanence: float = field(default=0.0, metadata={"boards": MAVLINK})
    # °/s the unit turns about its Z axis while it is held still for the current sweep (it slips in its fixture)
    moved_during_sweep: float = field(default=0.0, metadata={"boards": MAVLINK})
    # MAV_CMD_DO_MOTOR_TEST is refused (no RC calibration, a safety switch on)
    motor_test_refused: bool = field(default=False, metadata={"boards": MAVLINK})
    # "UT:TAU_S": every compass's offset is UT µT from its settled value while the board is cold and
    # settles with time constant TAU_S as it warms; a reboot keeps it warm (sim/thermal.py)
    mag_warmup: str = field(default="", metadata={"form": "UT:TAU_S"})
    # every compass's offset moves this many µT (along the warm-up's direction) at each cut of the board's
    # supply and stays there: a unit whose offset at the post-power-cycle check is not the one it was
    # calibrated with (a cold board after the cut, a sensor back from power-on in another state).  A
    # step, not a thermal decay, so the check it must fail does not depend on how quickly a machine
    # reaches it; a MAVLink reboot (no cut) leaves it.
    mag_offset_after_cut: float = 0.0
    # how the firmware applies a stored calibration where it does not as the real one does (PX4 only):
    # "sign" adds the offsets (a release that reads them the other way), "unit" reads them in
    # milligauss, "slot" applies the next slot's calibration to each compass, "none" stores the
    # calibration and never applies it.  The read-back of every parameter still matches.
    cal_applied: str = field(default="", metadata={"boards": ("px4",), "form": "sign|unit|slot|none"})
    # INAV over MSP: another firmware answers (its MSP_FC_VARIANT, "BTFL" for Betaflight); the unit is armed
    # (INAV refuses MSP_EEPROM_WRITE then, and ignores MSP_REBOOT); the board after the next reboot has
    # another MCU unique id (another board put in the cradle)
    msp_variant: str = field(default="", metadata={"boards": ("inav",), "form": "VARIANT"})
    armed: bool = field(default=False, metadata={"boards": ("inav",)})
    uid_changes_at_reboot: bool = field(default=False, metadata={"boards": ("inav",)})
    # PX4's factory calibration storage (/fs/mtd_caldata): a board without that partition ("cannot open
    # calibration storage"), an export that fails, a store that keeps the values it held before (a flash
    # write that did not take), and a unit moved during the gyro calibration that writes the store
    # ("Motion during calibration")
    no_factory_partition: bool = field(default=False, metadata={"boards": ("px4",)})
    factory_store_fails: bool = field(default=False, metadata={"boards": ("px4",)})
    factory_store_stale: bool = field(default=False, metadata={"boards": ("px4",)})
    moved_during_gyro_cal: bool = field(default=False, metadata={"boards": ("px4",)})

    BOARDS = ("px4", "ardupilot", "inav")  # a fault without ``boards`` in its metadata is every board's
    CAL_APPLIED = ("sign", "unit", "slot", "none")
    CURRENT_SENSOR = ("none", "bypassed")

    def __post_init__(self) -> None:
        if self.cal_applied and self.cal_applied not in self.CAL_APPLIED:
            raise ValueError(f"cal_applied must be one of {', '.join(self.CAL_APPLIED)}, not {self.cal_applied!r}")
        if self.link_stalls:
            try:
                hold, every = self.stalls() or (0.0, 0.0)
            except ValueError:
                hold = every = -1.0
            if not 0.0 < hold < every:
                raise ValueError(f"link_stalls must be HOLD_S:EVERY_S with 0 < HOLD_S < EVERY_S (seconds), not "
                                 f"{self.link_stalls!r}")
        if self.current_sensor and self.current_sensor not in self.CURRENT_SENSOR:
            raise ValueError(f"current_sensor must be one of {', '.join(self.CURRENT_SENSOR)}, "
                             f"not {self.current_sensor!r}")

    @classmethod
    def for_board(cls, board: str | None) -> list:
        """The faults a board's simulator has (all of them for None), as dataclass fields."""
        return [f for f in fields(cls) if board is None or board in f.metadata.get("boards", cls.BOARDS)]

    @classmethod
    def parse(cls, items: list[str], board: str | None = None) -> SimFaults:
        """From ``name[=value]`` strings, as given to ``--fault`` (lists are comma separated); with ``board``,
        a fault that board's simulator does not have is refused, naming the ones it has."""
        faults = cls()
        known = {f.name: f for f in cls.for_board(board)}
        for item in items:
            name, _, value = item.partition("=")
            name = name.strip().replace("-", "_")
            if name not in known:
                owners = [b for b in cls.BOARDS if name in {f.name for f in cls.for_board(b)}]
                whose = (f"{board}'s simulator has no fault {name!r} ({' and '.join(owners)}'s only)" if owners
                         else f"unknown fault {name!r}")
                raise ValueError(f"{whose}; known: {', '.join(known)}")
            current = getattr(faults, name)
            if isinstance(current, bool):
                setattr(faults, name, value.lower() not in ("0", "false", "no"))
            elif isinstance(current, list):
                setattr(faults, name, [v.strip() for v in value.split(",") if v.strip()])
            elif isinstance(current, str):
                setattr(faults, name, value.strip())
            elif name == "mag_missing_after_reboot":
                setattr(faults, name, int(value))
            else:
                setattr(faults, name, float(value))
        faults.__post_init__()
        return faults

    def stalls(self) -> tuple[float, float] | None:
        """(hold s, period s) of the ``link_stalls`` fault, or None (asked at every frame a board sends)."""
        return _hold_and_period(self.link_stalls) if self.link_stalls else None

    def warmup(self) -> tuple[float, float] | None:
        """(µT, time constant s) of the compasses' warm-up after boot, or None."""
        if not self.mag_warmup:
            return None
        size, _, tau = self.mag_warmup.partition(":")
        return float(size), float(tau or 3.0)

    def mountings(self) -> dict[int, tuple[int, float]]:
        """Sensor index (0-based) → (orientation value, yaw error in degrees) from the mounting faults."""
        out: dict[int, tuple[int, float]] = {}
        for item in self.mag_mounting:
            n, _, k = item.partition(":")
            out[int(n) - 1] = (int(k), out.get(int(n) - 1, (0, 0.0))[1])
        for item in self.mag_yaw_error:
            n, _, deg = item.partition(":")
            out[int(n) - 1] = (out.get(int(n) - 1, (0, 0.0))[0], float(deg))
        return out

    def latencies_s(self) -> dict[int, float]:
        """Sensor index (0-based) → how much older its readings are in its stream (s)."""
        out: dict[int, float] = {}
        for item in self.mag_latency:
            n, _, ms = item.partition(":")
            out[int(n) - 1] = float(ms) / 1000.0
        return out

    def acks_lost(self) -> dict[int, int]:
        """Command number → how many of its first acknowledgements are lost (the ``lose_command_acks`` fault)."""
        return {int(command): int(k) for command, _, k in (item.rpartition(":") for item in self.lose_command_acks)}

    def answers_lost(self) -> dict[str, int]:
        """NAME → how many of its first reads go unanswered (the ``lose_param_answers`` fault)."""
        return {name: int(k) for name, _, k in (item.rpartition(":") for item in self.lose_param_answers)}

    def ignores(self, name: str) -> bool:
        return "*" in self.ignore_param_set or name in self.ignore_param_set


@lru_cache(maxsize=8)
def _hold_and_period(text: str) -> tuple[float, float]:
    hold, _, every = text.partition(":")
    return float(hold), float(every or 1.0)
