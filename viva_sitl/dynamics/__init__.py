"""The Emulated Aerial Vehicle (EAV): pure, seeded, discrete dynamics in NED/FRD."""

from viva_sitl.dynamics.eav import disturbance_force_n, paper_update, step
from viva_sitl.dynamics.params import EavParams, WindParams
from viva_sitl.dynamics.rotation import euler_from_quat, quat_from_euler, rot_body_to_ned, wrap_pi
from viva_sitl.dynamics.state import EavCommand, EavState, floats3, vec3

__all__ = [
    "EavCommand",
    "EavParams",
    "EavState",
    "WindParams",
    "disturbance_force_n",
    "euler_from_quat",
    "paper_update",
    "quat_from_euler",
    "rot_body_to_ned",
    "step",
    "floats3",
    "vec3",
    "wrap_pi",
]
