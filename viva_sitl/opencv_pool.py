"""OpenCV's thread pool told to sleep, not spin, between its parallel calls (set when viva_sitl is imported).

Why: OpenCV's pthreads pool (the opencv-python wheels' parallel framework) keeps its workers and the calling thread
busy-waiting for a while after each parallel call (OPENCV_THREAD_POOL_ACTIVE_WAIT_* in OpenCV's parallel_impl.cpp).
A simulator step calls OpenCV a few times per frame on small images (a 640x480 warp, a colour conversion), so the
spinning is most of a worker's time: on the 2-core bench machine it cost 0.7-1.2 ms of CPU per step over the 4K
clip at 50 m (2.2-2.9 ms with it, 1.4-1.6 ms without), and the spinning threads took the core the tile decoder needed,
so steps per wall second rose too (bench/results_tiles.md, Session 16). With the waits at 0 a worker sleeps on its
condition variable as soon as it has no work; OpenCV's results do not depend on it (every output pixel is computed the
same way whatever thread computes it).

OpenCV reads the variables once, when its library is loaded. They are set in this process's environment (only those
the user has not set) when viva_sitl is imported: they apply to this process if cv2 is not loaded yet (the
`viva-sitl` commands, any program that imports viva_sitl or viva_sitl.gym before cv2) and to the processes it starts
(trial and Ray workers, `viva-sitl run` children) in any case. A program that imported cv2 first keeps OpenCV's
defaults in its own process unless it set the variables itself. The variables added here are not passed on to the
programs viva-sitl starts for the user (external pilots): `user_environ`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, MutableMapping

# OpenCV's names; its defaults (busy-wait iterations, static variables read when libopencv_core is loaded) are
# PAUSE_LIMIT 16, WORKER 2000, MAIN 10000 (modules/core/src/parallel_impl.cpp)
ACTIVE_WAIT_OFF = {
    "OPENCV_THREAD_POOL_ACTIVE_WAIT_PAUSE_LIMIT": "0",
    "OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER": "0",
    "OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN": "0",
}

# the names of the variables viva_sitl set (not the user), kept in the environment so that the processes that inherit
# it (trial and Ray workers) still know which ones to leave out of a user's program's environment. A listed variable
# whose value is no longer viva_sitl's was set again by the user (a shell prefix, os.environ in a notebook): it is
# the user's from then on.
SET_BY_VIVA_SITL = "VIVA_SITL_OPENCV_POOL_SET"


def _ours(env: Mapping[str, str]) -> set[str]:
    """The variables of SET_BY_VIVA_SITL's list that still hold the value viva_sitl gave them."""
    listed = {n for n in env.get(SET_BY_VIVA_SITL, "").split(",") if n}
    return {n for n in listed if n in ACTIVE_WAIT_OFF and env.get(n) == ACTIVE_WAIT_OFF[n]}


def configure(environ: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """Set the variables of ACTIVE_WAIT_OFF the environment does not have (default: this process's) and list, in
    SET_BY_VIVA_SITL, those that hold the value viva_sitl gave them. Returns the variables it set."""
    env = os.environ if environ is None else environ
    added = {k: v for k, v in ACTIVE_WAIT_OFF.items() if k not in env}
    env.update(added)
    names = _ours(env) | set(added)
    if names:
        env[SET_BY_VIVA_SITL] = ",".join(sorted(names))
    elif SET_BY_VIVA_SITL in env:
        del env[SET_BY_VIVA_SITL]
    return added


def user_environ(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """`environ` (default: this process's) without SET_BY_VIVA_SITL and the variables it lists that still hold
    viva_sitl's value: the environment for a program the user gave (it gets OpenCV's defaults, or what the user set;
    a user who sets one of them to viva_sitl's own value, 0, after importing viva_sitl cannot be told apart and the
    program gets OpenCV's default for it)."""
    env = os.environ if environ is None else environ
    ours = _ours(env) | {SET_BY_VIVA_SITL}
    return {k: v for k, v in env.items() if k not in ours}
