"""The web dashboard served by `viva-sitl run` (http://127.0.0.1:8080 + instance): the live VAC view, the overview
(footage, camera footprint, vehicle, trail, home, mission, geofence, ground-truth / risk layers), a HUD, the
STATUSTEXT log, and flying from the browser (buttons, keyboard, gamepad) through the autopilot's own code paths.

`Dashboard` (server.py) needs aiohttp (the `dashboard` extra); `DashboardConfig` and the pure parts
(control.py, vac.py, overview.py) do not. See server.py for the routes and control.py for who steers.
"""

from viva_sitl.dashboard.config import DEFAULT_PORT, DashboardConfig

__all__ = ["DEFAULT_PORT", "DashboardConfig"]
