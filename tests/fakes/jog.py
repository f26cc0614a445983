"""A jog by a separate RTDE client process, as a pendant program or another application moves the arm.

    python -m tests.fakes.jog --host 127.0.0.x [--moves 5] [--speed 1.0] [--acc 2.0] [--rest-s 1.0]
        [--every-s 0] [--seed 0] [--model UR5e] [--deadline-s S]

Connects with ur-rtde's ``RTDEControlInterface`` (its own control script, its own RTDE connection) and
``RTDEReceiveInterface`` (where the arm is), then makes ``--moves`` blocking ``moveJ`` moves at ``--speed`` rad/s
and ``--acc`` rad/s² to random targets around the start configuration, every joint moving (wrist included: each
joint travels at least :data:`MIN_FRACTION` of its amplitude, :data:`AMPLITUDE_RAD`), checked against the
project's collision and joint-limit model (``procedures.plan.check_path``); the last move returns to the start.
Between moves the arm rests ``--rest-s`` s, or, with ``--every-s T``, move k starts T × k s after the first.
Whoever reads the arm meanwhile (``ftacq monitor`` with ``RTDEReceiveInterface``) is another client of the same
controller, as on a real cell: a controller serves several RTDE clients, one control program at a time.

Prints one JSON line when connected (``{"ready": true, "q": [...]}``) and one per move
(``{"move": k, "start_s": ..., "end_s": ..., "target": [...], "from": [...]}``, host ``time.monotonic()``),
then ``{"done": true}``. Exits 0; 1 with a one-line error (a refused move, no connection); 2 when
``--deadline-s`` (default: the plan's duration + 30 s) passes first.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time

import numpy as np

from ftacq.kinematics.trapezoid import trapezoid_duration_s

AMPLITUDE_RAD = np.array([0.3, 0.25, 0.3, 1.0, 1.0, 1.5])
"""Largest excursion of each joint from the start configuration (rad): the wrist most, as a technician jogs."""
MIN_FRACTION = 0.3
"""Every joint travels at least this fraction of its amplitude on every move (so every joint moves)."""
MAX_TRIES = 500
"""Random targets drawn per move before giving up on a clear one."""
DEADLINE_MARGIN_S = 30.0
"""--deadline-s default: the plan's duration plus this (connecting, the controller's start-up), s."""
DEADLINE_EXIT = 2



def plan_targets(start: np.ndarray, moves: int, seed: int, model: str, speed: float,
                 acceleration: float) -> np.ndarray:
    """Return ``moves`` checked moveJ targets (moves, 6): random ones around ``start``, the last back at it."""
    from procedures.plan import PlanSettings, check_path

    settings = PlanSettings(model=model, joint_speed_rad_s=speed, joint_acceleration_rad_s2=acceleration)
    rng = np.random.default_rng(seed)
    targets, q = [], np.asarray(start, dtype=float)
    for _ in range(moves - 1):
        for _ in range(MAX_TRIES):
            fraction = rng.uniform(MIN_FRACTION, 1.0, 6) * rng.choice([-1.0, 1.0], 6)
            candidate = start + AMPLITUDE_RAD * fraction
            if np.all(np.abs(candidate - q) >= MIN_FRACTION * AMPLITUDE_RAD) and not check_path(settings, q, candidate):
                break
        else:
            raise RuntimeError(f"no clear jog target found in {MAX_TRIES} tries around {np.round(start, 3).tolist()}")
        targets.append(candidate)
        q = candidate
    targets.append(np.asarray(start, dtype=float))
    return np.array(targets)


def _emit(**values) -> None:
    print(json.dumps(values), flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.fakes.jog", description=__doc__.split("\n\n")[0])
    parser.add_argument("--host", required=True, help="the controller's address")
    parser.add_argument("--moves", type=int, default=5, help="moveJ moves, the last back to the start (default 5)")
    parser.add_argument("--speed", type=float, default=1.0, help="joint speed, rad/s (default 1.0)")
    parser.add_argument("--acc", type=float, default=2.0, help="joint acceleration, rad/s² (default 2.0)")
    parser.add_argument("--rest-s", type=float, default=1.0, help="rest after each move, s (default 1.0)")
    parser.add_argument("--every-s", type=float, default=0.0,
                        help="start move k at T × k s after the first (T > a move's duration; default 0: --rest-s)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random targets")
    parser.add_argument("--model", default="UR5e", help="UR model, for the collision and joint-limit check")
    parser.add_argument("--deadline-s", type=float, default=None,
                        help="give up (exit 2) after this long, s (default: the plan's duration + 30 s)")
    args = parser.parse_args(argv)
    if args.moves < 1 or args.speed <= 0 or args.acc <= 0 or args.rest_s < 0 or args.every_s < 0:
        print("jog: --moves ≥ 1, --speed and --acc > 0, --rest-s and --every-s ≥ 0", file=sys.stderr)
        return 1

    def deadline_passed(*_) -> None:
        print(f"jog: deadline passed ({args.deadline_s:.0f} s)", file=sys.stderr, flush=True)
        sys.stdout.flush()
        import os

        os._exit(DEADLINE_EXIT)  # ur-rtde's threads may hold a blocking call: leave at once

    estimate_s = args.moves * (max(args.every_s, trapezoid_duration_s(2 * AMPLITUDE_RAD.max(), args.speed, args.acc)
                                   + args.rest_s))
    args.deadline_s = args.deadline_s or estimate_s + DEADLINE_MARGIN_S
    signal.signal(signal.SIGALRM, deadline_passed)
    signal.setitimer(signal.ITIMER_REAL, args.deadline_s)

    import rtde_control
    import rtde_receive

    try:
        receive = rtde_receive.RTDEReceiveInterface(args.host)
        control = rtde_control.RTDEControlInterface(args.host)
    except RuntimeError as error:
        print(f"jog: cannot connect to the controller at {args.host}: {error}", file=sys.stderr)
        return 1
    try:
        start = np.array(receive.getActualQ())
        targets = plan_targets(start, args.moves, args.seed, args.model, args.speed, args.acc)
        _emit(ready=True, q=start.tolist())
        first_s = None
        for k, target in enumerate(targets):
            if first_s is not None:
                due = first_s + k * args.every_s if args.every_s > 0 else time.monotonic() + args.rest_s
                while (wait := due - time.monotonic()) > 0:
                    time.sleep(wait)  # the rest between moves (the jog's own pace, not synchronisation)
            q_from = np.array(receive.getActualQ())
            started = time.monotonic()
            first_s = started if first_s is None else first_s
            if not control.moveJ(target.tolist(), args.speed, args.acc):
                print(f"jog: move {k + 1} refused by the controller", file=sys.stderr)
                return 1
            _emit(move=k + 1, start_s=started, end_s=time.monotonic(), target=target.tolist(), **{"from": q_from.tolist()})
        if args.every_s <= 0:  # the rest after the last move too (a reader lagging behind still sees it at rest)
            due = time.monotonic() + args.rest_s
            while (wait := due - time.monotonic()) > 0:
                time.sleep(wait)
        _emit(done=True)
        return 0
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        control.stopScript()
        control.disconnect()
        receive.disconnect()


if __name__ == "__main__":
    sys.exit(main())
