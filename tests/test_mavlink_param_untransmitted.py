"""PX4's parameter change broadcast (MavlinkParametersManager::send_untransmitted): a PARAM_SET that changes a value
is answered at once and the changed value is broadcast once more a few ms later; MAVSDK's parameter subscriptions
(its failure plugin's SYS_FAILURE_EN) only see that second PARAM_VALUE. An unchanged value is answered once."""

from __future__ import annotations

import asyncio
import struct
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot import ParamStore
from viva_sitl.mavlink.base import Component, LinkKind, Origin
from viva_sitl.mavlink.params import ParamProtocol


class Recorder:
    def __init__(self) -> None:
        self.sent: list[Any] = []

    def reply(self, origin: Origin, msg: Any, component: Component = Component.AUTOPILOT) -> None:
        self.sent.append(msg)

    def broadcast(self, msg: Any, component: Component = Component.AUTOPILOT) -> None:
        self.sent.append(msg)


def _set_int(name: str, value: int) -> Any:
    wire = struct.unpack("<f", struct.pack("<i", value))[0]
    return mavlink2.MAVLink_param_set_message(1, 1, name.encode(), wire, mavlink2.MAV_PARAM_TYPE_INT32)


def test_a_changed_parameter_is_announced_again_and_an_unchanged_one_is_not() -> None:
    async def scenario() -> tuple[list[str], list[str]]:
        out = Recorder()
        proto = ParamProtocol(ParamStore(), out, lambda *a: None)  # type: ignore[arg-type]
        task = asyncio.create_task(proto.run())
        origin = Origin(LinkKind.GCS, ("127.0.0.1", 14550), 255, 190)
        proto.handle_set(origin, _set_int("SYS_FAILURE_EN", 1))
        await asyncio.sleep(0.1)
        changed = [m.param_id for m in out.sent]
        out.sent.clear()
        proto.handle_set(origin, _set_int("SYS_FAILURE_EN", 1))  # the same value again
        await asyncio.sleep(0.1)
        task.cancel()
        return changed, [m.param_id for m in out.sent]

    changed, unchanged = asyncio.run(scenario())
    assert changed == ["SYS_FAILURE_EN", "SYS_FAILURE_EN"]
    assert unchanged == ["SYS_FAILURE_EN"]
