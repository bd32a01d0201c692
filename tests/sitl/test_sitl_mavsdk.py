"""The SITL seen by MAVSDK 4 (the native binding) as an independent client, in real time.

MAVSDK is the strictest client we have: it decides "armable", "position ok", the flight mode
and the landed state from HEARTBEAT, SYS_STATUS, EXTENDED_SYS_STATE and HOME_POSITION alone,
and gives up on commands that get no COMMAND_ACK. These tests use MAVSDK directly, not the
companion's link, so that they check the SITL and nothing else.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable, Iterator
from contextlib import asynccontextmanager
from typing import Any, TypeVar

import pytest

from companion.link.mavsdk_convert import route_mavsdk_log
from companion.simulator import SitlProcess, start_sitl
from tests.conftest import free_port

pytest.importorskip("mavsdk")

pytestmark = [pytest.mark.realtime, pytest.mark.e2e]

SPEED = 2.0  # sim s per wall s: MAVSDK's wall-clock timeouts (3 s heartbeat) stay comfortable
T = TypeVar("T")


@pytest.fixture
def sitl_udp() -> Iterator[tuple[SitlProcess, int]]:
    """A real-time SITL sending to a free loopback UDP port, where MAVSDK will listen."""
    port = free_port()
    sitl = start_sitl(port, clock="realtime", camera=False, extra_args=["--speed", str(SPEED)])
    try:
        yield sitl, port
    finally:
        sitl.stop()


class Drone:
    """The MAVSDK plugins one test needs, created and destroyed together."""

    def __init__(self, system: Any) -> None:
        from mavsdk.asyncio.plugins.action import ActionAsync
        from mavsdk.asyncio.plugins.offboard import OffboardAsync
        from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

        self.action = ActionAsync(system)
        self.offboard = OffboardAsync(system)
        self.telemetry = TelemetryAsync(system)

    def destroy(self) -> None:
        for plugin in (self.action, self.offboard, self.telemetry):
            plugin.destroy()


@asynccontextmanager
async def connected_drone(port: int, timeout_s: float = 10.0) -> AsyncIterator[Drone]:
    """MAVSDK listening on ``port`` until it finds the SITL's autopilot; always cleaned up."""
    from mavsdk.asyncio import Configuration, Mavsdk
    from mavsdk.component_type import ComponentType

    route_mavsdk_log()  # MAVSDK prints its log to stdout: to Python logging (shown on failure)
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as mavsdk:
        await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = await mavsdk.first_autopilot(timeout_s)
        assert system is not None, f"MAVSDK found no autopilot on UDP {port} within {timeout_s} s"
        drone = Drone(system)
        try:
            yield drone
        finally:
            drone.destroy()


async def first(stream: AsyncIterator[T], ok: Callable[[T], bool], timeout_s: float, what: str) -> T:
    """The first value of a MAVSDK subscription that satisfies ``ok``; the stream is closed after."""

    async def scan() -> T:
        async for value in stream:
            if ok(value):
                return value
        raise AssertionError(f"{what}: the stream ended")

    try:
        return await asyncio.wait_for(scan(), timeout_s)
    except asyncio.TimeoutError:
        raise AssertionError(f"{what}: not seen within {timeout_s} s") from None
    finally:
        await stream.aclose()  # type: ignore[attr-defined]


async def wait_healthy_and_armed(drone: Drone) -> None:
    """What a MAVSDK user does first: wait for armable + position, arm, see it armed."""
    health = await first(drone.telemetry.subscribe_health(),
                         lambda h: h.is_armable and h.is_local_position_ok and h.is_global_position_ok
                         and h.is_home_position_ok, 10.0, "health: armable, positions and home ok")  # fmt: skip
    assert health.is_gyrometer_calibration_ok and health.is_accelerometer_calibration_ok
    await first(drone.telemetry.subscribe_landed_state(), lambda s: s.name == "ON_GROUND", 5.0, "on ground")
    await drone.action.arm()
    await first(drone.telemetry.subscribe_armed(), bool, 5.0, "armed")


async def take_off(drone: Drone, alt_m: float) -> None:
    await drone.action.set_takeoff_altitude(alt_m)
    await drone.action.takeoff()
    await first(drone.telemetry.subscribe_in_air(), bool, 5.0, "in air")
    await first(drone.telemetry.subscribe_position_velocity_ned(),
                lambda pv: pv.position.down_m < -(alt_m - 0.3), 10.0, f"climbed to {alt_m} m")  # fmt: skip
    await first(drone.telemetry.subscribe_flight_mode(), lambda m: m.name == "HOLD", 10.0, "hold after takeoff")


async def position_velocity(drone: Drone) -> Any:
    return await first(drone.telemetry.subscribe_position_velocity_ned(), lambda _: True, 3.0, "position")


def run(coro: Any, timeout_s: float) -> Any:
    """Run one scenario on a fresh event loop with an overall bound."""
    return asyncio.run(asyncio.wait_for(coro, timeout_s))


def test_mavsdk_flies_offboard_body_velocity_and_lands(sitl_udp: tuple[SitlProcess, int]) -> None:
    """The whole PX4 offboard recipe as MAVSDK's examples fly it: health, arm, takeoff,
    offboard body velocity (forward, then right), stop to hold, land, disarm."""
    sitl, port = sitl_udp

    async def scenario() -> dict[str, float]:
        from mavsdk.plugins.offboard import VelocityBodyYawspeed

        async with connected_drone(port) as drone:
            mode = await first(drone.telemetry.subscribe_flight_mode(), lambda m: m.name != "UNKNOWN", 5.0, "mode")
            assert mode.name == "HOLD"  # PX4's AUTO.LOITER, as MAVSDK names it
            await wait_healthy_and_armed(drone)
            await take_off(drone, 2.0)
            start = await position_velocity(drone)
            await drone.offboard.set_velocity_body(VelocityBodyYawspeed(0.0, 0.0, 0.0, 0.0))
            await drone.offboard.start()
            await first(drone.telemetry.subscribe_flight_mode(), lambda m: m.name == "OFFBOARD", 5.0, "offboard")
            await drone.offboard.set_velocity_body(VelocityBodyYawspeed(1.0, 0.0, 0.0, 0.0))
            moving = await first(drone.telemetry.subscribe_position_velocity_ned(),
                                 lambda pv: pv.position.north_m - start.position.north_m > 2.0, 8.0,
                                 "2 m forward")  # fmt: skip
            await drone.offboard.set_velocity_body(VelocityBodyYawspeed(0.0, 1.0, 0.0, 0.0))
            sideways = await first(drone.telemetry.subscribe_position_velocity_ned(),
                                   lambda pv: pv.velocity.east_m_s > 0.8, 5.0, "moving right")  # fmt: skip
            assert await drone.offboard.is_active()
            await drone.offboard.stop()
            await first(drone.telemetry.subscribe_flight_mode(), lambda m: m.name == "HOLD", 5.0, "hold after stop")
            await drone.action.land()
            await first(drone.telemetry.subscribe_landed_state(), lambda s: s.name == "ON_GROUND", 15.0, "landed")
            await first(drone.telemetry.subscribe_armed(), lambda a: not a, 5.0, "disarmed")
            return {"fwd_vn": moving.velocity.north_m_s, "fwd_ve": moving.velocity.east_m_s,
                    "fwd_down": moving.position.down_m - start.position.down_m,
                    "right_ve": sideways.velocity.east_m_s}  # fmt: skip

    seen = run(scenario(), 45.0)
    assert seen["fwd_vn"] == pytest.approx(1.0, abs=0.25)  # heading 0: forward is north
    assert abs(seen["fwd_ve"]) < 0.25
    assert abs(seen["fwd_down"]) < 0.3  # altitude held while flying
    assert seen["right_ve"] == pytest.approx(1.0, abs=0.25)
    assert sitl.proc.poll() is None
