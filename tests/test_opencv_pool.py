"""viva_sitl.opencv_pool: importing viva_sitl tells OpenCV's thread pool to sleep instead of spinning (the variables
OpenCV reads when it is loaded, set before anything imports cv2), keeps what the user set, and gives the user's
programs their own environment, also from processes that inherited it (trial workers) and after the user set one
again."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from viva_sitl import opencv_pool

REPO = Path(__file__).resolve().parents[1]
NAMES = sorted(opencv_pool.ACTIVE_WAIT_OFF)
MARK = opencv_pool.SET_BY_VIVA_SITL

PROBE = """
import json, os, sys
import viva_sitl
cv2_before = "cv2" in sys.modules  # what OpenCV would have read had importing viva_sitl loaded it
from viva_sitl import opencv_pool
import numpy as np
import cv2
names = sorted(opencv_pool.ACTIVE_WAIT_OFF)
print(json.dumps({"cv2_loaded_by_import": cv2_before,
                  "env": {k: os.environ.get(k) for k in names},
                  "user": {k: opencv_pool.user_environ().get(k) for k in names},
                  "marker_to_user": opencv_pool.SET_BY_VIVA_SITL in opencv_pool.user_environ(),
                  "child_env": {k: os.environ.get(k) for k in names + [opencv_pool.SET_BY_VIVA_SITL]},
                  "warp_ok": int(cv2.warpAffine(np.full((8, 8), 7, np.uint8), np.eye(2, 3), (8, 8)).max())}))
"""


def _shell_env() -> dict[str, str]:
    """A fresh shell's environment: this process's without the OpenCV pool variables (viva_sitl's or a developer's
    own) and the list of those viva_sitl set."""
    return {k: v for k, v in opencv_pool.user_environ().items() if not k.startswith("OPENCV_THREAD_POOL")}


def _probe(env: dict[str, str]) -> dict[str, Any]:
    r = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, cwd=REPO,
                       timeout=120, check=True)  # fmt: skip
    out: dict[str, Any] = json.loads(r.stdout.strip().splitlines()[-1])
    return out


def test_import_sets_the_pool_variables_before_cv2_and_the_users_programs_do_not_get_them() -> None:
    got = _probe(_shell_env())
    assert got["cv2_loaded_by_import"] is False  # else OpenCV would have read its defaults already
    assert got["env"] == {k: "0" for k in NAMES}
    assert got["user"] == {k: None for k in NAMES}  # a pilot started by viva-sitl gets OpenCV's defaults
    assert got["marker_to_user"] is False
    assert got["warp_ok"] == 7  # OpenCV works as before in that process


def test_a_value_the_user_set_is_kept_and_passed_on() -> None:
    got = _probe(_shell_env() | {"OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN": "500"})
    assert got["env"]["OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN"] == "500"
    assert got["env"]["OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER"] == "0"
    assert got["user"] == {k: ("500" if k == "OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN" else None) for k in NAMES}


def test_a_child_that_inherits_viva_sitls_variables_still_leaves_them_out_and_keeps_what_the_user_set_again() -> (
    None
):
    # what a trial worker, or `viva-sitl trials` started from a program that imported viva_sitl, inherits
    inherited = _shell_env() | {k: "0" for k in NAMES} | {MARK: ",".join(NAMES)}
    got = _probe(inherited)
    assert got["user"] == {k: None for k in NAMES} and got["marker_to_user"] is False
    # the same, but the user set one of them again on the way (`OPENCV_..._MAIN=500 viva-sitl trials ...`)
    got = _probe(inherited | {"OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN": "500"})
    assert got["env"]["OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN"] == "500"
    assert got["user"] == {k: ("500" if k == "OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN" else None) for k in NAMES}
    assert (
        got["child_env"][MARK]
        == "OPENCV_THREAD_POOL_ACTIVE_WAIT_PAUSE_LIMIT,OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER"
    )


def test_configure_and_user_environ_on_a_given_mapping() -> None:
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
    # set again by the user in this process (a notebook's os.environ): theirs from then on
    child["OPENCV_THREAD_POOL_ACTIVE_WAIT_PAUSE_LIMIT"] = "16"
    assert opencv_pool.user_environ(child)["OPENCV_THREAD_POOL_ACTIVE_WAIT_PAUSE_LIMIT"] == "16"
    assert "OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN" not in opencv_pool.user_environ(child)
