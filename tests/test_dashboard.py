"""The dashboard's WebSocket protocol against a real `viva-sitl run`: who steers, bad input, sticks that expire.

A real process and a real aiohttp WebSocket client; effects are checked through MAVLink (a pymavlink peer) and
/api/state, as a second program would see them.
"""

from __future__ import annotations

import asyncio
import json
import math
import time
from collections.abc import Callable
from typing import Any

import pytest
from sitl_process import MavlinkPeer, SitlProcess, free_tcp_port

aiohttp = pytest.importorskip("aiohttp", reason="aiohttp is in the dashboard/test extras")

pytestmark = [pytest.mark.e2e, pytest.mark.slow]  # slow: each test flies a viva-sitl + its dashboard
ARMED_FLAG = 128


def _url(sitl: SitlProcess) -> str:
    for part in sitl.ready_line.split(" | "):
        if part.startswith("dashboard http"):
            return part.split(" ", 1)[1].rstrip("/")
    raise AssertionError(sitl.ready_line)


async def _next(
    ws: Any, kind: str, timeout_s: float = 5.0, pred: Callable[[dict[str, Any]], bool] = lambda m: True
) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise AssertionError(f"no {kind!r} message within {timeout_s} s")
        msg = await ws.receive(timeout=left)
        if msg.type != aiohttp.WSMsgType.TEXT:
            raise AssertionError(f"socket ended: {msg.type}")
        data = json.loads(msg.data)
        if data.get("t") == kind and pred(data):
            return data


async def _state(session: Any, base: str) -> dict[str, Any]:
    async with session.get(f"{base}/api/state") as r:
        assert r.status == 200
        return dict(await r.json())


async def _wait_state(
    session: Any, base: str, pred: Callable[[dict[str, Any]], bool], timeout_s: float, what: str
) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    st: dict[str, Any] = {}
    while time.monotonic() < deadline:
        st = await _state(session, base)
        if pred(st):
            return st
        await asyncio.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}; last state rc={st.get('rc')} mode={st.get('mode')}")


@pytest.fixture
def dash(sitl_factory: Callable[..., SitlProcess]) -> SitlProcess:
    return sitl_factory(extra_args=["--dashboard-port", str(free_tcp_port())])


def test_last_page_to_take_control_wins_the_other_is_read_only(dash: SitlProcess) -> None:
    base = _url(dash)

    async def run() -> None:
        async with (
            aiohttp.ClientSession() as s,
            s.ws_connect(f"{base}/ws") as a,
            s.ws_connect(f"{base}/ws") as b,
        ):
            assert (await _next(a, "hello"))["role"] == "read-only"
            await _next(b, "hello")
            # nobody has control: a command is refused with the reason
            await a.send_str(json.dumps({"t": "cmd", "id": 1, "cmd": "arm"}))
            ack = await _next(a, "ack")
            assert not ack["ok"] and "Take control" in ack["reason"]
            await a.send_str(json.dumps({"t": "take_control"}))
            assert (await _next(a, "role"))["role"] == "pilot"
            await b.send_str(json.dumps({"t": "take_control"}))
            assert (await _next(b, "role"))["role"] == "pilot"
            lost = await _next(a, "role")
            assert lost["role"] == "read-only" and "took control" in lost["reason"]
            # A is read-only now: its sticks and commands are refused; B's are taken
            await a.send_str(json.dumps({"t": "sticks", "x": 1.0, "y": 0.0, "z": 0.5, "r": 0.0}))
            assert "read-only" in (await _next(a, "error"))["reason"]
            await a.send_str(json.dumps({"t": "cmd", "id": 2, "cmd": "mode", "mode": "POSCTL"}))
            assert not (await _next(a, "ack"))["ok"]
            await b.send_str(json.dumps({"t": "sticks", "x": 0.0, "y": 0.4, "z": 0.5, "r": 0.0}))
            st = await _wait_state(s, base, lambda st: st["rc"]["sticks"]["y"] == 0.4, 5, "B's sticks")
            assert st["rc"]["pilot_page"] is not None and st["dashboard"]["control"]["not_pilot"] >= 2
            await b.send_str(json.dumps({"t": "cmd", "id": 3, "cmd": "mode", "mode": "POSCTL"}))
            ack = await _next(b, "ack")
            assert ack["ok"], ack["reason"]

    asyncio.run(run())
    assert dash.alive


def test_malformed_messages_and_out_of_range_sticks_are_ignored_and_counted(dash: SitlProcess) -> None:
    base = _url(dash)
    with MavlinkPeer(dash.ports.gcs) as peer:
        peer.wait_autopilot()

        async def run() -> None:
            async with aiohttp.ClientSession() as s, s.ws_connect(f"{base}/ws") as ws:
                await _next(ws, "hello")
                await ws.send_str(json.dumps({"t": "take_control"}))
                await _next(ws, "role")
                await ws.send_str(json.dumps({"t": "sticks", "x": 0.0, "y": 0.0, "z": 0.5, "r": 0.0}))
                bad: list[str | bytes] = [
                    "{not json", "[1, 2]", '"text"', json.dumps({"t": 5}), json.dumps({"t": "fly-me"}),
                    json.dumps({"t": "cmd", "cmd": "selfdestruct"}), json.dumps({"t": "cmd", "cmd": "mode", "mode": 7}),
                    b"\x00\x01binary",
                ]  # fmt: skip
                out_of_range = [
                    {"x": 5.0, "y": 0, "z": 0.5, "r": 0}, {"x": 0, "y": -1.5, "z": 0.5, "r": 0},
                    {"x": 0, "y": 0, "z": 1.2, "r": 0}, {"x": 0, "y": 0, "z": 0.5}, {"x": "1", "y": 0, "z": 0.5, "r": 0},
                    {"x": float("nan"), "y": 0, "z": 0.5, "r": 0}, {"x": True, "y": 0, "z": 0.5, "r": 0},
                ]  # fmt: skip
                for m in bad:
                    await (ws.send_bytes(m) if isinstance(m, bytes) else ws.send_str(m))
                for st in out_of_range:
                    await ws.send_str(json.dumps({"t": "sticks", **st}))  # NaN goes out as a bare NaN token
                state = await _wait_state(
                    s, base, lambda st: st["dashboard"]["control"]["out_of_range"] >= len(out_of_range), 5,
                    "out-of-range sticks counted",
                )  # fmt: skip
                assert state["dashboard"]["bad_messages"] >= len(bad)
                # nothing bad was taken
                assert state["rc"]["sticks"] == {"x": 0.0, "y": 0.0, "z": 0.5, "r": 0.0}
                # the page still works: a valid command after all that
                await ws.send_str(json.dumps({"t": "cmd", "id": 9, "cmd": "mode", "mode": "POSCTL"}))
                assert (await _next(ws, "ack", pred=lambda m: m["id"] == 9))["ok"]
            async with aiohttp.ClientSession() as s, s.ws_connect(f"{base}/ws") as ws:
                await _next(ws, "hello")
                await ws.send_str("x" * 100_000)
                msg = await ws.receive(timeout=5)
                while msg.type == aiohttp.WSMsgType.TEXT:  # telemetry sent before the server read the big one
                    msg = await ws.receive(timeout=5)
                assert msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED), msg
                assert ws.close_code == 1009  # message too big: only this socket ends
            async with aiohttp.ClientSession() as s:
                async with s.get(f"{base}/api/overview.jpg?x0=abc") as r:
                    assert r.status == 400 and "must be numbers" in await r.text()
                async with s.get(f"{base}/api/overview.jpg?x0=1e9&x1=2e9") as r:
                    assert r.status == 400 and "outside the footage" in await r.text()
                assert (await _state(s, base))["mode"] == "POSCTL"

        asyncio.run(run())
        peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1 and m.custom_mode == 3 << 16, 5)
    assert dash.alive


def test_sticks_expire_and_a_closed_page_leaves_them_centred_while_the_vehicle_holds(
    dash: SitlProcess,
) -> None:
    base = _url(dash)
    with MavlinkPeer(dash.ports.gcs) as peer:
        peer.wait_autopilot()

        async def run() -> None:
            async with aiohttp.ClientSession() as s:
                async with s.ws_connect(f"{base}/ws") as ws:
                    await _next(ws, "hello")
                    await ws.send_str(json.dumps({"t": "take_control"}))
                    await _next(ws, "role")
                    for cmd in ({"cmd": "mode", "mode": "POSCTL"}, {"cmd": "arm"}, {"cmd": "takeoff"}):
                        await ws.send_str(json.dumps({"t": "cmd", **cmd}))
                        ack = await _next(ws, "ack")
                        assert ack["ok"], ack["reason"]
                    await _wait_state(s, base, lambda st: st["alt_agl_m"] > 2.3 and abs(st["vertical_speed_m_s"]) < 0.2,
                                      40, "the take-off to end")  # fmt: skip
                    await ws.send_str(json.dumps({"t": "cmd", "cmd": "mode", "mode": "POSCTL"}))
                    assert (await _next(ws, "ack"))["ok"]
                    # one stick message, then silence: taken, then centred after stick_timeout_s (0.5 s)
                    await ws.send_str(json.dumps({"t": "sticks", "x": 0.0, "y": 1.0, "z": 0.5, "r": 0.0}))
                    await _wait_state(
                        s, base, lambda st: st["rc"]["sticks"]["y"] == 1.0, 5, "the sticks taken"
                    )
                    st = await _wait_state(
                        s, base, lambda st: st["rc"]["sticks"]["y"] == 0.0, 5, "the sticks expired"
                    )
                    assert st["rc"]["feeding"]
                    # steer east continuously, then close the socket mid-stick
                    for _ in range(40):
                        await ws.send_str(json.dumps({"t": "sticks", "x": 0.0, "y": 1.0, "z": 0.5, "r": 0.0}))
                        st = await _state(s, base)
                        if st["vel_ned_m_s"][1] > 2.0:
                            break
                        await asyncio.sleep(0.05)
                    assert st["vel_ned_m_s"][1] > 2.0, st["vel_ned_m_s"]
                st = await _wait_state(
                    s, base, lambda st: st["rc"]["pilot_page"] is None, 5, "the pilot gone"
                )
                assert st["rc"]["sticks"] == {"x": 0.0, "y": 0.0, "z": 0.5, "r": 0.0} and st["rc"]["feeding"]
                st = await _wait_state(
                    s, base, lambda st: st["ground_speed_m_s"] < 0.3, 30, "the vehicle to brake"
                )
                assert st["mode"] == "POSCTL" and st["armed"]  # holding in Position, no RC-loss failsafe

        asyncio.run(run())
        # MAVLink agrees: still POSCTL and armed, hovering
        hb = peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1, 5)
        assert hb.custom_mode == 3 << 16 and hb.base_mode & ARMED_FLAG
        pos = peer.wait("LOCAL_POSITION_NED", timeout_s=5)
        assert pos.z < -2.0 and math.hypot(pos.vx, pos.vy) < 0.5
    assert dash.alive


def test_busy_explicit_port_is_a_one_line_error_and_default_port_falls_back(tmp_path: Any) -> None:
    import socket

    with socket.socket() as blocker:
        blocker.bind(("127.0.0.1", 0))
        blocker.listen()
        port = blocker.getsockname()[1]
        proc = SitlProcess(workdir=tmp_path, extra_args=["--dashboard-port", str(port)], name="busy")
        with pytest.raises(Exception) as err:
            proc.start()
        proc.stop()
        assert f"cannot listen on 127.0.0.1:{port}" in str(err.value)
        assert proc.returncode == 2


def test_direct_mode_flies_roll_pitch_yaw_rate_thrust_through_offboard_attitude(dash: SitlProcess) -> None:
    base = _url(dash)
    with MavlinkPeer(dash.ports.gcs) as peer:
        peer.wait_autopilot()

        async def run() -> None:
            async with aiohttp.ClientSession() as s, s.ws_connect(f"{base}/ws") as ws:
                await _next(ws, "hello")
                await ws.send_str(json.dumps({"t": "take_control"}))
                await _next(ws, "role")
                # take off first, as a pilot would, then switch to the direct mode
                for i, cmd in enumerate(({"cmd": "arm"}, {"cmd": "takeoff"})):
                    await ws.send_str(json.dumps({"t": "cmd", "id": i, **cmd}))
                    assert (await _next(ws, "ack", pred=lambda m, i=i: m["id"] == i))["ok"]
                await _wait_state(
                    s,
                    base,
                    lambda st: st["alt_agl_m"] > 2.3 and abs(st["vertical_speed_m_s"]) < 0.2,
                    40,
                    "hover",
                )
                await ws.send_str(json.dumps({"t": "cmd", "id": 10, "cmd": "mode", "mode": "DIRECT"}))
                ack = await _next(ws, "ack", pred=lambda m: m["id"] == 10)
                assert ack["ok"], ack["reason"]
                st = await _wait_state(s, base, lambda st: st["mode"] == "DIRECT", 5, "DIRECT on the HUD")
                assert st["px4_mode"] == "OFFBOARD"
                t0 = time.monotonic()
                # right stick half right: the vehicle rolls right (the direct mode's roll = y * max tilt)
                while time.monotonic() - t0 < 1.5:
                    await ws.send_str(json.dumps({"t": "sticks", "x": 0.0, "y": 0.3, "z": 0.5, "r": 0.0}))
                    st = await _state(s, base)
                    if st["att_deg"][0] > 10.0:
                        break
                    await asyncio.sleep(0.05)
                assert st["att_deg"][0] > 10.0, st["att_deg"]
                # silence: sticks centred -> level attitude at hover thrust
                await _wait_state(s, base, lambda st: abs(st["att_deg"][0]) < 2.0, 10, "level again")
                await ws.send_str(json.dumps({"t": "cmd", "id": 11, "cmd": "mode", "mode": "POSCTL"}))
                assert (await _next(ws, "ack", pred=lambda m: m["id"] == 11))["ok"]
                await _wait_state(s, base, lambda st: st["mode"] == "POSCTL", 5, "POSCTL after DIRECT")

        asyncio.run(run())
        rolled = [m for m in peer.messages("ATTITUDE") if m.roll > math.radians(10)]
        assert rolled, "MAVLink never reported the direct-mode roll"
        assert any(m.custom_mode == 6 << 16 for m in peer.messages("HEARTBEAT", component=1))
    assert dash.alive


def test_websocket_from_another_web_origin_is_refused(dash: SitlProcess) -> None:
    """Cross-site WebSocket hijacking: a page from another site open in the same browser cannot steer."""
    base = _url(dash)
    host = base.split("://", 1)[1]

    async def run() -> None:
        async with aiohttp.ClientSession() as s:
            for path in ("/ws", "/ws/vac"):
                with pytest.raises(aiohttp.WSServerHandshakeError) as err:
                    await s.ws_connect(f"{base}{path}", headers={"Origin": "http://evil.example"})
                assert err.value.status == 403
            async with s.ws_connect(
                f"{base}/ws", headers={"Origin": f"http://{host}"}
            ) as ws:  # the page itself
                assert (await _next(ws, "hello"))["role"] == "read-only"

    asyncio.run(run())


def test_altitude_mode_throttle_climbs_and_centred_holds_as_manual_control_does(dash: SitlProcess) -> None:
    base = _url(dash)

    async def run() -> None:
        async with aiohttp.ClientSession() as s, s.ws_connect(f"{base}/ws") as ws:
            await _next(ws, "hello")
            await ws.send_str(json.dumps({"t": "take_control"}))
            await _next(ws, "role")
            # throttle high on the ground: arming refused with PX4's reason, as over MANUAL_CONTROL
            await ws.send_str(json.dumps({"t": "cmd", "id": 1, "cmd": "mode", "mode": "ALTCTL"}))
            assert (await _next(ws, "ack", pred=lambda m: m["id"] == 1))["ok"]
            await ws.send_str(json.dumps({"t": "sticks", "x": 0.0, "y": 0.0, "z": 0.9, "r": 0.0}))
            await ws.send_str(json.dumps({"t": "cmd", "id": 2, "cmd": "arm"}))
            ack = await _next(ws, "ack", pred=lambda m: m["id"] == 2)
            assert not ack["ok"] and ack["reason"] == "Arming denied: throttle above center"
            await ws.send_str(json.dumps({"t": "sticks", "x": 0.0, "y": 0.0, "z": 0.5, "r": 0.0}))
            await ws.send_str(json.dumps({"t": "cmd", "id": 3, "cmd": "arm"}))
            assert (await _next(ws, "ack", pred=lambda m: m["id"] == 3))["ok"]
            t0 = time.monotonic()
            st = await _state(s, base)
            while time.monotonic() - t0 < 20 and st["alt_agl_m"] < 3.0:  # throttle up: climb
                await ws.send_str(json.dumps({"t": "sticks", "x": 0.0, "y": 0.0, "z": 1.0, "r": 0.0}))
                await asyncio.sleep(0.05)
                st = await _state(s, base)
            assert st["alt_agl_m"] >= 3.0 and st["mode"] == "ALTCTL", st
            for _ in range(60):  # centred throttle: altitude hold
                await ws.send_str(json.dumps({"t": "sticks", "x": 0.0, "y": 0.0, "z": 0.5, "r": 0.0}))
                await asyncio.sleep(0.05)
                st = await _state(s, base)
                if abs(st["vertical_speed_m_s"]) < 0.1:
                    break
            alt = st["alt_agl_m"]
            st = await _wait_state(
                s, base, lambda x: x["sim_time_s"] > st["sim_time_s"] + 2.0, 10, "2 s of sim"
            )
            assert abs(st["alt_agl_m"] - alt) < 0.5 and st["armed"]
            await ws.send_str(json.dumps({"t": "cmd", "id": 4, "cmd": "mode", "mode": "STABILIZED"}))
            assert (await _next(ws, "ack", pred=lambda m: m["id"] == 4))["ok"]

    asyncio.run(run())
    assert dash.alive
