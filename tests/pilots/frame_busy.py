"""A companion-computer pilot for lockstep tests and benches:
`python frame_busy.py MAVLINK_URL FRAME_SOCKET_URL [LO_MS,HI_MS] [FIRST_MS]` (default 20,40 and none).

It reads the frame-and-pose socket (viva_sitl's FrameClient), computes LO-HI ms of CPU per frame (seeded by the
trial index), and flies velocity setpoints from each frame's pose toward a spot 5 m south of where it was told to
land; below 2 m it commands LAND. MAVLink only between frames (non-blocking). FIRST_MS: the first frame it acts on
costs that much CPU instead (a model's warm-up on its first input)."""

import json
import os
import random
import sys
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil

from viva_sitl.video.frame_socket import FrameClient

with open(os.environ["VIVA_SITL_SCENARIO"]) as f:
    scenario = json.load(f)
rng = random.Random(scenario["index"])
lo, hi = (float(x) / 1000.0 for x in (sys.argv[3] if len(sys.argv) > 3 else "20,40").split(","))
first_s = float(sys.argv[4]) / 1000.0 if len(sys.argv) > 4 else None
m = mavutil.mavlink_connection(sys.argv[1], source_system=255)
m.wait_heartbeat(timeout=30)
m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
mask = 0b0000_1111_1100_0111
state, target = "wait", None
with FrameClient(sys.argv[2], latest_only=False, rcvhwm=4) as client:
    while True:
        while (msg := m.recv_match(blocking=False)) is not None:
            t = msg.get_type()
            if t == "STATUSTEXT" and "land now" in msg.text and state == "wait":
                state = "offboard"
            elif (
                t == "HEARTBEAT"
                and msg.get_srcSystem() == m.target_system
                and state == "landing"
                and not msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
            ):
                print("disarmed: done", flush=True)
                sys.exit(0)
        item = client.receive(timeout_s=0.5)
        if item is None or state in ("wait", "landing"):
            continue
        n, e, d = item[1]["pos_ned_m"]
        if target is None:
            target = (n - 5.0, e)
        work = rng.uniform(lo, hi)
        if first_s is not None:
            work, first_s = first_s, None
        end = time.thread_time() + work
        while time.thread_time() < end:
            pass
        vn, ve = max(-3.0, min(3.0, target[0] - n)), max(-3.0, min(3.0, target[1] - e))
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
        elif -d < 2.0:
            m.mav.command_long_send(
                m.target_system, 1, mavutil.mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0
            )
            state = "landing"
