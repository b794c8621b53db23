"""A pilot that never waits (busy polling): `python spinner.py MAVLINK_URL`. Lockstep cannot hold it."""

import os
import sys

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil

m = mavutil.mavlink_connection(sys.argv[1], source_system=255)
m.wait_heartbeat(timeout=30)
m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
while True:  # busy polling: never waits for anything
    m.recv_match(blocking=False)
