"""What one simulated board's attitude costs (printed, never asserted): ``spiral_attitude`` at one instant, the
simulators' hot path, against its defining composition of four scipy ``Rotation`` objects, and the largest
difference between the two over a tumble's instants; then a board on a turning turntable: its attitude's
matrix as scipy composes it and as ``MotionFollower.matrix`` computes it.

    python benchmarks/sim_attitude.py [--calls 5000] [--repeat 5]
"""

from __future__ import annotations

import argparse
import statistics
import timeit

import numpy as np
from scipy.spatial.transform import Rotation

from magline.sim.truth.attitudes import ROCK_PERIOD_S, ROCK_RAD, field_frame, spiral_angles, spiral_attitude

FIELD_DIR = np.array([0.47, 0.0, 0.88])


def composed(t: float) -> Rotation:
    """NED → body = Rz(φ)·Ry(θ)·Rz(ψ)·F, inverted: the attitude as the simulators define it."""
    phi, theta = spiral_angles(t)
    psi = ROCK_RAD * np.sin(2 * np.pi * t / ROCK_PERIOD_S)
    return (Rotation.from_rotvec([0.0, 0.0, float(phi)]) * Rotation.from_rotvec([0.0, float(theta), 0.0])
            * Rotation.from_rotvec([0.0, 0.0, float(psi)]) * field_frame(FIELD_DIR)).inv()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--calls", type=int, default=5000)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    for name, call in (("spiral_attitude (one quaternion product)", lambda: spiral_attitude(1.234, FIELD_DIR)),
                       ("four composed Rotations", lambda: composed(1.234))):
        runs = timeit.repeat(call, number=args.calls, repeat=args.repeat)
        print(f"{name:42s} median {statistics.median(runs) / args.calls * 1e6:7.1f} µs a call")
    t = np.linspace(0.0, 40.0, 801)
    worst = max(np.abs(spiral_attitude(float(x), FIELD_DIR).as_matrix() - composed(float(x)).as_matrix()).max()
                for x in t)
    print(f"largest difference of the two matrices over {len(t)} instants: {worst:.1e}")
    turntable(args.calls, args.repeat)


def turntable(calls: int, repeat: int) -> None:
    """A board's view of a table turning a tilted cradle: the two ways to its matrix, timed at one instant."""
    import time

    from magline.sim.gimbal import MotionFollower
    from magline.sim.turntable import TurntableSim

    table = TurntableSim("tcp:127.0.0.1:0", homed=True, reaction_s=0.0).start()
    follower = MotionFollower(table.address)
    try:
        table.set_tilt(45.0, -30.0)
        time.sleep(0.6)  # the cradle's move over
        table.command("ROT:TURN", "1")
        time.sleep(0.3)
        at = time.monotonic() - 0.1
        for name, call in (("turntable: scipy Rotation, as_matrix", lambda: follower.attitude(at).as_matrix()),
                           ("turntable: MotionFollower.matrix", lambda: follower.matrix(at))):
            runs = timeit.repeat(call, number=calls, repeat=repeat)
            print(f"{name:42s} median {statistics.median(runs) / calls * 1e6:7.1f} µs a call")
    finally:
        follower.stop()
        table.stop()


if __name__ == "__main__":
    main()
