"""viva_sitl.opencv_pool: importing viva_sitl tells OpenCV's thread pool to sleep instead of spinning (the variables
OpenCV reads when it is loaded), keeps what the user set, and gives the user's programs their own environment."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from viva_sitl import opencv_pool

REPO = Path(__file__).resolve().parents[1]
NAMES = sorted(opencv_pool.ACTIVE_WAIT_OFF)

PROBE = """
import json, os, sys
import viva_sitl
from viva_sitl import opencv_pool
import numpy as np
import cv2  # loaded after viva_sitl: the variables are in place when OpenCV reads them
names = sorted(opencv_pool.ACTIVE_WAIT_OFF)
print(json.dumps({"env": {k: os.environ.get(k) for k in names},
                  "user": {k: opencv_pool.user_environ().get(k) for k in names},
                  "warp_ok": int(cv2.warpAffine(np.full((8, 8), 7, np.uint8), np.eye(2, 3), (8, 8)).max())}))
"""


def _probe(extra_env: dict[str, str]) -> dict[str, dict[str, str | None]]:
    # a fresh shell's environment: this process's without what importing viva_sitl set in it
    env = opencv_pool.user_environ() | extra_env
    r = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, cwd=REPO,
                       timeout=120, check=True)  # fmt: skip
    out: dict[str, dict[str, str | None]] = json.loads(r.stdout.strip().splitlines()[-1])
    return out


def test_import_sets_the_pool_variables_and_the_users_programs_do_not_get_them() -> None:
    got = _probe({})
    assert got["env"] == {k: "0" for k in NAMES}
    assert got["user"] == {k: None for k in NAMES}  # a pilot started by viva-sitl gets OpenCV's defaults
    assert got["warp_ok"] == 7  # OpenCV works as before in that process


def test_a_value_the_user_set_is_kept_and_passed_on() -> None:
    got = _probe({"OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN": "500"})
    assert got["env"]["OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN"] == "500"
    assert got["env"]["OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER"] == "0"
    assert got["user"] == {k: ("500" if k == "OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN" else None) for k in NAMES}


def test_configure_on_a_given_mapping() -> None:
    env = {"OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER": "3", "HOME": "/x"}
    added = opencv_pool.configure(env)
    assert added == {
        "OPENCV_THREAD_POOL_ACTIVE_WAIT_PAUSE_LIMIT": "0",
        "OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN": "0",
    }
    assert env["OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER"] == "3" and env["HOME"] == "/x"
    # a process that inherits this environment (a trial worker) adds nothing, and still leaves out the same ones
    child = dict(env)
    assert opencv_pool.configure(child) == {}
    assert opencv_pool.user_environ(child) == {"OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER": "3", "HOME": "/x"}
