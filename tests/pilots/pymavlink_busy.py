"""A pymavlink pilot for lockstep tests and benches: `python pymavlink_busy.py MAVLINK_URL LO_MS,HI_MS`.

Told to land ("land now" STATUSTEXT), it flies offboard velocity setpoints toward a spot 6 m north-east of where it
was, descending, one setpoint per LOCAL_POSITION_NED it receives; each one costs it LO-HI ms of CPU time (seeded by
the trial index), then below 2 m it commands LAND. Its wall-clock heartbeat timer does not steer."""

import json
import os
import random
import sys
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil

with open(os.environ["VIVA_SITL_SCENARIO"]) as f:
    scenario = json.load(f)
lo, hi = (float(x) for x in sys.argv[2].split(","))
rng = random.Random(scenario["index"])
m = mavutil.mavlink_connection(sys.argv[1], source_system=255)
m.wait_heartbeat(timeout=30)
m.mav.command_long_send(
    m.target_system, 1, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 32, 50000, 0, 0, 0, 0, 0
)
OFFBOARD = 6 << 16
mask = 0b0000_1111_1100_0111  # velocities only
state, target, last_hb = "wait", None, 0.0
while True:
    if time.monotonic() - last_hb > 1.0:
        m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        last_hb = time.monotonic()
    msg = m.recv_match(type=["STATUSTEXT", "HEARTBEAT", "LOCAL_POSITION_NED"], blocking=True, timeout=0.5)
    if msg is None:
        continue
    t = msg.get_type()
    if t == "STATUSTEXT" and "land now" in msg.text and state == "wait":
        state = "offboard"
    elif t == "LOCAL_POSITION_NED" and state in ("offboard", "flying"):
        if target is None:
            target = (msg.x + 6.0, msg.y + 6.0)
        end = time.thread_time() + rng.uniform(lo, hi) / 1000.0  # a fixed amount of work, however loaded
        while time.thread_time() < end:
            pass
        vn = max(-3.0, min(3.0, 0.8 * (target[0] - msg.x)))
        ve = max(-3.0, min(3.0, 0.8 * (target[1] - msg.y)))
        m.mav.set_position_target_local_ned_send(
            0,
            m.target_system,
            1,
            mavutil.mavlink.MAV_FRAME_LOCAL_NED,
            mask,
            0,
            0,
            0,
            vn,
            ve,
            1.5,
            0,
            0,
            0,
            0,
            0,
        )
        if state == "offboard":
            m.mav.command_long_send(
                m.target_system,
                1,
                mavutil.mavlink.MAV_CMD_DO_SET_MODE,
                0,
                mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                6,
                0,
                0,
                0,
                0,
                0,
            )
            state = "flying"
        elif -msg.z < 2.0:
            m.mav.command_long_send(
                m.target_system, 1, mavutil.mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0
            )
            state = "landing"
    elif (
        t == "HEARTBEAT"
        and msg.get_srcSystem() == m.target_system
        and state == "landing"
        and not msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    ):
        print("disarmed: done", flush=True)
        break
