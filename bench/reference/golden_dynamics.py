"""Golden trajectories of the REFERENCE dynamics (viva-safeland 0.2.0, `viva.modules.simulator.Drone`).

Runs under the reference's interpreter and prints JSON: for a fixed, varied command sequence, the reference's
positions (its frame: x forward, y left, z up) after every step, plus the same converted to NED and the
equivalent NED/FRD commands. `bench/bench_core.py --check-dynamics` replays them through our
`viva_sitl.dynamics.step` with `EavParams.paper()` and reports the largest difference.

    /work/venv312/bin/python bench/reference/golden_dynamics.py > /tmp/golden.json

Frame change (derivation in NOTES.md): NED = (x, -y, -z); roll = phi, pitch = -theta, yaw = -psi;
total thrust T = m g + fk.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import sys

with contextlib.redirect_stdout(io.StringIO()):  # `import viva` imports pygame, which prints a banner
    from viva.modules.simulator import Drone


def commands(n: int) -> list[tuple[float, float, float, float]]:
    """(phi_deg, theta_deg, psi_rate_deg_s, fk_n): a smooth, varied sequence inside both models' limits."""
    out = []
    for k in range(n):
        t = k / 30.0
        out.append(
            (
                12.0 * math.sin(0.7 * t),
                -9.0 * math.sin(0.45 * t + 0.3),
                25.0 * math.cos(0.3 * t),
                0.8 * math.sin(0.9 * t),
            )
        )
    return out


def main() -> int:
    fps = 30
    n = 300
    x0, y0, z0, psi0 = 3.0, -2.0, 40.0, 20.0
    drone = Drone(fps=fps)
    drone.reset(x0, y0, z0, psi0)
    rows = []
    for phi, theta, rate, fk in commands(n):
        drone.move(phi, theta, rate, fk)
        p = drone.state[1].pos  # after move(): state[0] and state[1] both hold X_k (simulator.py:84-91)
        rows.append(
            {
                "cmd_ref": [phi, theta, rate, fk],
                "psi_deg_used": drone.psi_deg,  # yaw is updated *before* the force is computed (simulator.py:59)
                "cmd_ned": {
                    "roll_rad": math.radians(phi),
                    "pitch_rad": -math.radians(theta),
                    "yaw_rad": -math.radians(drone.psi_deg),
                    "thrust_n": drone.fkeq + fk,
                },
                "pos_ref": [p.x, p.y, p.z],
                "pos_ned_m": [p.x, -p.y, -p.z],
            }
        )
    json.dump(
        {
            "reference": "viva-safeland 0.2.0 viva.modules.simulator.Drone",
            "fps": fps,
            "mass_kg": drone.mass,
            "drag_kd": drone.kd,
            "g": drone.g,
            "start_ref": [x0, y0, z0, psi0],
            "start_ned_m": [x0, -y0, -z0],
            "steps": rows,
        },
        sys.stdout,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
