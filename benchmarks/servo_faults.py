"""Servo faults -> what actuator.dynamixel says, how long it takes to say it, and the torque state
after.

    .venv/bin/python benchmarks/servo_faults.py [--retries 3] [--late-window-ms 250]

Each row injects one fault into the AX-12A emulator (real dynamixel-sdk over a pseudo-terminal) and
runs a pick plan with the actuator's default parameters (motion 50x faster than real time); the
same cases are asserted in tests/test_arm_servo_faults.py. Seconds to fail = from the call to the
error (the emulator adds no latency of its own beyond the injected one). Torque = the servos'
torque-enable registers afterwards (1 = holding).
"""

from __future__ import annotations

import argparse
import time

from nodes.actuators.dynamixel import DynamixelParams, execute_plan
from nodes.calibrators.hand_eye import HandEyeParams, hand_eye
from nodes.ik.analytic_3dof import AnalyticParams, analytic_3dof
from nodes.ik.arm import ArmParams, build_arm_model
from nodes.ik.pick_sequence import PickParams, pick_sequence
from simbench.servo_sim import ERR_ANGLE, ERR_OVERHEAT, ERR_OVERLOAD, ERR_VOLTAGE, Faults, ServoSim
from stereograph.core.api import NodeError

IDS = [1, 2, 3, 4, 5]


def plan_and_arm():
    arm = build_arm_model(ArmParams())
    he = hand_eye(
        HandEyeParams(
            mode="given", camera_in_base={"translation_cm": [0, 0, 0], "rpy_deg": [0, 0, 0]}
        )
    )
    loc = {
        "pair": "p1",
        "found": True,
        "reason": None,
        "x_cm": 17.0,
        "y_cm": 4.0,
        "z_cm": 2.5,
        "frame": "left_camera",
    }
    t = analytic_3dof(AnalyticParams(), arm=arm, location=loc, hand_eye=he["hand_eye"])["target"]
    return pick_sequence(PickParams(), arm=arm, target=t)["plan"], arm


def cases(plan):
    g4 = plan["waypoints"][0]["servo_units"]["4"]
    jam = (512 + g4) / 2

    def torque_on(sim):
        for i in (1, 2, 4, 5):
            sim.servos[i].table[24] = 1

    def srl0(sim):
        sim.servos[2].table[16] = 0

    return [
        ("no reply (servo 3 unplugged)", Faults(unplugged_ids={3}), None, {}),
        ("no reply, torque left on by an earlier run", Faults(unplugged_ids={3}), torque_on, {}),
        (
            "  same, torque_off_on_failure: true",
            Faults(unplugged_ids={3}),
            torque_on,
            {"torque_off_on_failure": True},
        ),
        (
            "late replies (70 ms) at ping",
            Faults(late_replies=10**6, late_ms=70, only_ids={3}),
            None,
            {},
        ),
        ("corrupted replies", Faults(corrupt_replies=10**6, only_ids={2}), None, {}),
        ("overload bit at ping", Faults(alarms={4: ERR_OVERLOAD}), None, {}),
        ("overheating bit at ping", Faults(alarms={4: ERR_OVERHEAT}), None, {}),
        ("input voltage bit at ping", Faults(alarms={4: ERR_VOLTAGE}), None, {}),
        ("angle limit bit at ping", Faults(alarms={4: ERR_ANGLE}), None, {}),
        (
            "PING ok, 4 READ replies lost",
            Faults(drop_replies=4, instructions={"READ"}, only_ids={5}),
            None,
            {},
        ),
        (
            "PING+WRITE ok, every READ lost",
            Faults(drop_replies=10**6, instructions={"READ"}, only_ids={5}),
            None,
            {},
        ),
        ("status return level 0", Faults(), srl0, {}),
        (
            "jammed elbow (overload while moving)",
            Faults(jammed_at_units={4: jam}, jam_alarm_s=0.3),
            None,
            {},
        ),
        (
            "stalled elbow, no alarm (move_timeout_s 2)",
            Faults(jammed_at_units={4: jam}, jam_alarm_s=1e9),
            None,
            {"move_timeout_s": 2.0},
        ),
        (
            "overheating bit while moving",
            Faults(alarms={2: ERR_OVERHEAT}, after_goal_writes=1),
            None,
            {},
        ),
        (
            "late replies while moving",
            Faults(late_replies=10**6, late_ms=70, only_ids={1}, after_goal_writes=1),
            None,
            {},
        ),
        (
            "no reply while moving",
            Faults(drop_replies=10**6, only_ids={4}, after_goal_writes=1),
            None,
            {},
        ),
        (
            "corrupted replies while moving",
            Faults(corrupt_replies=10**6, only_ids={4}, after_goal_writes=1),
            None,
            {},
        ),
    ]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--retries", type=int, default=3)
    ap.add_argument("--late-window-ms", type=float, default=250.0)
    ap.add_argument("--head-chars", type=int, default=110, help="characters of the message shown")
    a = ap.parse_args(argv)
    plan, arm = plan_and_arm()
    print("| fault | message head | s to fail | torque after (ids 1-5) |")
    print("|---|---|---|---|")
    for name, faults, setup, extra in cases(plan):
        params = DynamixelParams(
            port="sim",
            sim_time_scale=50.0,
            retries=a.retries,
            late_window_ms=a.late_window_ms,
            **extra,
        )
        with ServoSim(IDS, faults=faults, time_scale=50.0) as sim:
            if setup:
                setup(sim)
            t0 = time.monotonic()
            try:
                execute_plan(params, plan, arm, sim.port_path)
                head = "(no failure)"
            except NodeError as e:
                head = e.message
            dt = time.monotonic() - t0
            torque = "".join(str(sim.register(i, "torque_enable")) for i in IDS)
        head = head if len(head) <= a.head_chars else head[: a.head_chars] + "..."
        print(f"| {name} | {head.replace('|', '/')} | {dt:.2f} | {torque} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
