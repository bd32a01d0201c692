"""The :class:`VehicleLink` over MAVSDK 4 (the native binding, asyncio API), for PX4 vehicles.

Real time only: MAVSDK stamps and re-sends setpoints itself (20 Hz), so a setpoint cannot echo
a lockstep frame marker; against a lockstep SITL each frame would wait out the SITL's timeout.
``wait_frame`` returns the next ATTITUDE update. Position and attitude are read as raw MAVLink
(MavlinkDirect) and folded by the pymavlink link's rules, so each carries the vehicle's own stamp
(MAVSDK's telemetry plugin gives a position without one). No tlog either (MAVSDK only exposes the bytes
it sends); use the pymavlink link when a recording is needed. MAVSDK runs on its own event-loop
thread; its log goes to the ``mavsdk`` logger instead of stdout.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import companion.link.px4_modes as px4_modes
from companion.config import LinkConfig
from companion.errors import CommandRejected, ConfigError, LinkLost, LinkTimeout
from companion.link.async_runner import AsyncRunner
from companion.link.base import LinkStats, ManualControlCallback, SetpointLimits, VehicleLink
from companion.link.manual_control import (
    addressed_to_us,
    deliver_manual_control,
    manual_control_from_fields,
)
from companion.link.mavlink_link import message_id
from companion.link.mavlink_link import result_name as mav_result_name
from companion.link.mavsdk_convert import (
    AUTOPILOT_COMPONENT,
    DIRECT_TELEMETRY,
    DIRECT_TRUTH,
    fold_direct_telemetry,
    fold_direct_truth,
    fold_flight_mode,
    fold_landed_state,
    initial_snapshot,
    mavsdk_url,
    route_mavsdk_log,
    translate_result,
)
from companion.link.waiters import wait_until
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import VehicleSnapshot

log = logging.getLogger(__name__)
MAV_CMD_REQUEST_MESSAGE = 512  # MAVLink common.xml
MAV_CMD_SET_MESSAGE_INTERVAL = 511


class MavsdkLink(VehicleLink):
    """MAVSDK implementation (PX4 only, real time only)."""

    def __init__(self, cfg: LinkConfig, tlog_path: str | Path | None = None) -> None:
        if tlog_path is not None:
            raise ConfigError(
                "the MAVSDK link cannot record a .tlog (MAVSDK does not expose received bytes); "
                "use the pymavlink link, or record with MAVProxy alongside"
            )
        if cfg.signing_key_file:
            raise ConfigError(
                "the MAVSDK link does not sign MAVLink (companion.link.signing_key_file is set); "
                "use the pymavlink link, which signs everything it sends"
            )
        self.cfg = cfg
        self.url = mavsdk_url(cfg.connection, cfg.baud)
        self._limits = SetpointLimits(
            cfg.setpoint_max_speed_m_s, cfg.setpoint_max_yaw_rate_rad_s, cfg.setpoint_max_distance_m
        )
        self._runner: AsyncRunner | None = None
        self._mavsdk: Any = None
        self._system: Any = None
        self._plugins: dict[str, Any] = {}
        self._snapshot: VehicleSnapshot | None = None
        self._changed = threading.Condition()
        self._last_heard_s: float | None = None
        self._was_alive = False
        self._counts: Counter[str] = Counter()
        self._manual_cb: ManualControlCallback | None = None
        self._offboard_ready = False
        self._closed = False

    # ================================================================ lifecycle
    def connect(self, timeout_s: float | None = None) -> VehicleSnapshot:
        timeout_s = self.cfg.heartbeat_timeout_s if timeout_s is None else timeout_s
        if self._closed:
            raise LinkLost("this link was closed; open a new one")
        if self._runner is None:
            route_mavsdk_log()
            self._runner = AsyncRunner("mavsdk-link")
        try:
            self._runner.run(self._connect(timeout_s), timeout_s + 2.0)
        except TimeoutError:
            self._system = None
        if self._system is None:
            raise LinkTimeout(
                f"MAVSDK found no autopilot on {self.url} within {timeout_s} s; check the "
                "connection string and that the vehicle or SITL is running"
            )
        snapshot = self._wait(lambda s: s is not None and s.mode != "UNKNOWN", timeout_s)
        if snapshot is None:
            raise LinkTimeout("the autopilot was found but sent no HEARTBEAT with its mode")
        if self.cfg.request_rates_on_connect:
            self.request_rates()
        return snapshot

    async def _connect(self, timeout_s: float) -> None:
        from mavsdk.asyncio import Configuration, Mavsdk
        from mavsdk.asyncio.plugins.action import ActionAsync
        from mavsdk.asyncio.plugins.offboard import OffboardAsync
        from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

        if self._mavsdk is None:
            config = Configuration.create_manual(
                self.cfg.source_system, self.cfg.source_component, True
            )
            self._mavsdk = Mavsdk(config)
            await self._mavsdk.add_any_connection(self.url)
        self._system = await self._mavsdk.first_autopilot(timeout_s)
        if self._system is None:
            return
        system_id = await self._system.get_system_id()
        autopilot = (await self._system.autopilot_type()).name
        self._plugins = {"telemetry": TelemetryAsync(self._system),
                         "action": ActionAsync(self._system),
                         "offboard": OffboardAsync(self._system)}  # fmt: skip
        self._publish(initial_snapshot(system_id, autopilot, time.monotonic()))
        self._start_streams()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._runner is not None:
            self._runner.stop()
        for plugin in self._plugins.values():
            plugin.destroy()
        self._plugins = {}
        if self._mavsdk is not None:
            self._mavsdk.destroy()
            self._mavsdk = None
        with self._changed:
            self._changed.notify_all()

    # ================================================================ telemetry
    def _start_streams(self) -> None:
        from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync

        tel = self._plugins["telemetry"]
        direct = self._plugins["direct_telemetry"] = MavlinkDirectAsync(self._system)
        streams: list[tuple[Any, Callable[[VehicleSnapshot, Any], VehicleSnapshot]]] = [
            *((direct.subscribe_message(name), fold_direct_telemetry) for name in DIRECT_TELEMETRY),
            *((direct.subscribe_message(name), fold_direct_truth) for name in DIRECT_TRUTH),
            (tel.subscribe_armed(), lambda s, v: replace(s, armed=bool(v))),
            (tel.subscribe_flight_mode(), fold_flight_mode),
            (tel.subscribe_landed_state(), fold_landed_state),
        ]
        for stream, fold in streams:
            _background(self._follow(stream, fold))
        _background(self._follow_manual_control())

    async def _follow(
        self, stream: Any, fold: Callable[[VehicleSnapshot, Any], VehicleSnapshot]
    ) -> None:
        async for value in stream:
            now = time.monotonic()
            self._heard(now)
            snapshot = self._snapshot
            if snapshot is None:
                continue
            try:
                new = fold(snapshot, value)
            except ValueError:
                self._counts["telemetry_rejected"] += 1
                continue
            self._counts["messages_received"] += 1
            self._publish(replace(new, received_s=now))

    async def _follow_manual_control(self) -> None:
        """MANUAL_CONTROL from any system MAVSDK knows of (a ground station is its own system)."""
        from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync

        followed: set[int] = set()

        async def follow_new_systems() -> None:
            for system in await self._mavsdk.get_systems():
                system_id = await system.get_system_id()
                if system_id not in followed:
                    followed.add(system_id)
                    log.info("following MANUAL_CONTROL from system %d", system_id)
                    direct = MavlinkDirectAsync(system)
                    self._plugins[f"direct{system_id}"] = direct
                    _background(self._follow_direct(direct))

        while True:  # polled: on_new_system does not fire for a sender without HEARTBEAT
            await follow_new_systems()
            await asyncio.sleep(0.5)

    async def _follow_direct(self, direct: Any) -> None:
        async for message in direct.subscribe_message("MANUAL_CONTROL"):
            self._manual_control(message)

    def _manual_control(self, message: Any) -> None:
        self._counts["manual_control_received"] += 1
        fields = json.loads(message.fields_json)
        snapshot = self._snapshot
        vehicle = snapshot.system_id if snapshot else None
        if addressed_to_us(int(fields.get("target", 0)), self.cfg.source_system, vehicle):
            value = manual_control_from_fields(
                fields, message.system_id, message.component_id, time.monotonic()
            )
            deliver_manual_control(value, message.system_id, self._counts, self._manual_cb)

    def _heard(self, now: float) -> None:
        if self._last_heard_s is not None and not self.link_alive():
            self._counts["reconnections"] += 1
            log.warning("MAVSDK link back after loss")
        self._last_heard_s = now

    def _publish(self, snapshot: VehicleSnapshot) -> None:
        with self._changed:
            self._snapshot = snapshot
            self._changed.notify_all()

    # ================================================================ state
    def state(self) -> VehicleSnapshot | None:
        return self._snapshot

    def link_alive(self) -> bool:
        heard = self._last_heard_s
        alive = heard is not None and time.monotonic() - heard < self.cfg.link_lost_s
        if self._was_alive and not alive:
            self._counts["link_losses"] += 1
        self._was_alive = alive
        return alive

    def stats(self) -> LinkStats:
        self.link_alive()
        return LinkStats(**dict(self._counts))

    def on_manual_control(self, callback: ManualControlCallback | None) -> None:
        self._manual_cb = callback

    def wait_frame(self, after_time_boot_ms: int, timeout_s: float) -> VehicleSnapshot | None:
        self._require_alive()
        return self._wait(
            lambda s: s is not None and (s.frame_time_boot_ms or -1) > after_time_boot_ms,
            timeout_s, raise_on_loss=True)  # fmt: skip

    def _wait(
        self,
        ready: Callable[[VehicleSnapshot | None], bool],
        timeout_s: float,
        raise_on_loss: bool = False,
    ) -> VehicleSnapshot | None:
        def check_link() -> None:
            if raise_on_loss and not self.link_alive():
                raise self._lost_error()

        return wait_until(self._changed, lambda: self._snapshot, ready, timeout_s, time.monotonic,
                          lambda: self._closed, check_link)

    # ================================================================ commands
    def arm(self) -> None:
        self._call("arm", self._plugins_checked()["action"].arm())

    def disarm(self) -> None:
        self._call("disarm", self._plugins_checked()["action"].disarm())

    def set_mode(self, name: str) -> None:
        mode = px4_modes.canonical_name(name)
        plugins = self._plugins_checked()
        action, offboard = plugins["action"], plugins["offboard"]
        leaving_offboard = self._snapshot is not None and self._snapshot.mode == "OFFBOARD"
        if mode == "OFFBOARD":
            if not self._offboard_ready:  # MAVSDK needs a setpoint before start()
                self.send_velocity_body(VelocitySetpoint.zero())
            self._call("set_mode('OFFBOARD')", offboard.start())
        elif mode == "AUTO.LOITER":
            self._call(
                "set_mode('AUTO.LOITER')", offboard.stop() if leaving_offboard else action.hold()
            )
        elif mode in ("AUTO.LAND", "AUTO.RTL", "AUTO.TAKEOFF"):
            method = {"AUTO.LAND": action.land, "AUTO.RTL": action.return_to_launch,
                      "AUTO.TAKEOFF": action.takeoff}[mode]  # fmt: skip
            self._call(f"set_mode({mode!r})", method())
        else:
            raise CommandRejected(
                f"set_mode({name!r})",
                "UNSUPPORTED",
                "MAVSDK cannot select this mode; use the pymavlink link",
            )

    def takeoff(self, alt_m: float) -> None:
        if not (math.isfinite(alt_m) and 0.0 < alt_m <= self.cfg.takeoff_max_alt_m):
            raise ValueError(
                f"takeoff altitude {alt_m} m must be in (0, {self.cfg.takeoff_max_alt_m}]"
            )
        action = self._plugins_checked()["action"]
        self._call("set_takeoff_altitude", action.set_takeoff_altitude(float(alt_m)))
        self._call("takeoff", action.takeoff())

    def land(self) -> None:
        self._call("land", self._plugins_checked()["action"].land())

    def request_rates(self, rates_hz: Mapping[str, float] | None = None) -> dict[str, str]:
        tel = self._plugins_checked()["telemetry"]
        setters = {"ATTITUDE": (tel.set_rate_attitude_euler,),
                   "LOCAL_POSITION_NED": (tel.set_rate_position_velocity_ned,),
                   "EXTENDED_SYS_STATE": (tel.set_rate_landed_state,)}  # fmt: skip
        if rates_hz is None:
            fast, slow = self.cfg.telemetry_rate_hz, self.cfg.status_rate_hz
            rates_hz = {"ATTITUDE": fast, "LOCAL_POSITION_NED": fast, "EXTENDED_SYS_STATE": slow}
            rates_hz = {k: v for k, v in rates_hz.items() if v > 0}
        results: dict[str, str] = {}
        for name, hz in rates_hz.items():
            if name not in setters:  # no plugin streams it: MAV_CMD_SET_MESSAGE_INTERVAL, raw
                results[name] = self._set_message_interval(name, hz)
                continue
            try:
                self._call(f"rate {name}", setters[name][0](float(hz)))
                results[name] = "ACCEPTED"
            except CommandRejected as exc:
                results[name] = exc.result
            except LinkTimeout:
                results[name] = "TIMEOUT"
        return results

    def request_message(
        self, message_name: str, component_id: int = 1, timeout_s: float = 2.0
    ) -> dict[str, Any] | None:
        """REQUEST_MESSAGE through MAVSDK's MavlinkDirect plugin (it resends until ACKed)."""
        msg_id = message_id(message_name)
        self._plugins_checked()
        request = self._request_message(message_name, msg_id, component_id, timeout_s)
        try:
            return self._runner.run(request, timeout_s + 2.0)  # type: ignore[union-attr]
        except TimeoutError:
            return None

    async def _request_message(
        self, message_name: str, msg_id: int, component_id: int, timeout_s: float
    ) -> dict[str, Any] | None:
        direct = self._direct_requests()
        reply = asyncio.ensure_future(_first_from(direct, message_name, component_id))
        await asyncio.sleep(0)  # let the subscription start before the request goes out
        try:
            ack = await self._send_request(direct, msg_id, component_id, timeout_s)
            if ack is not None and ack not in ("ACCEPTED", "IN_PROGRESS"):
                raise CommandRejected(f"REQUEST_MESSAGE({message_name}) to component {component_id}",
                                      ack, "the component does not offer this message")  # fmt: skip
            return await asyncio.wait_for(reply, timeout_s)
        except TimeoutError:
            return None
        finally:
            reply.cancel()

    def _set_message_interval(self, message_name: str, rate_hz: float) -> str:
        """MAV_CMD_SET_MESSAGE_INTERVAL through MavlinkDirect: the ACK's MAV_RESULT name."""
        try:
            msg_id = message_id(message_name)
        except ValueError:
            return "UNSUPPORTED"
        interval_us = 1e6 / rate_hz if rate_hz > 0 else -1.0  # -1: stop the stream
        timeout_s = self.cfg.command_timeout_s
        command = self._send_command_long(self._direct_requests(), MAV_CMD_SET_MESSAGE_INTERVAL,
                                          (float(msg_id), interval_us), AUTOPILOT_COMPONENT, timeout_s)
        try:
            return self._runner.run(command, timeout_s + 2.0) or "TIMEOUT"  # type: ignore[union-attr]
        except TimeoutError:
            return "TIMEOUT"

    def _direct_requests(self) -> Any:
        from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync

        direct = self._plugins.get("direct_requests")
        if direct is None:
            direct = self._plugins["direct_requests"] = MavlinkDirectAsync(self._system)
        return direct

    async def _send_request(
        self, direct: Any, msg_id: int, component_id: int, timeout_s: float
    ) -> str | None:
        """COMMAND_LONG REQUEST_MESSAGE; the ACK's MAV_RESULT name, None if none came."""
        return await self._send_command_long(direct, MAV_CMD_REQUEST_MESSAGE, (float(msg_id),), component_id,
                                             timeout_s)

    async def _send_command_long(
        self, direct: Any, command_id: int, params: tuple[float, ...], component_id: int, timeout_s: float
    ) -> str | None:
        """One COMMAND_LONG (params from param1; the rest 0); the ACK's MAV_RESULT name, None if
        none came."""
        from mavsdk.plugins.mavlink_direct import MavlinkDirectError, MavlinkMessage

        snapshot = self._require_alive()
        values = [*params, *([0.0] * (7 - len(params)))]
        fields = {"target_system": snapshot.system_id, "target_component": component_id,
                  "command": command_id, "confirmation": 0,
                  **{f"param{i + 1}": float(v) for i, v in enumerate(values)}}  # fmt: skip
        command = MavlinkMessage("COMMAND_LONG", self.cfg.source_system, self.cfg.source_component,
                                 snapshot.system_id, component_id, json.dumps(fields))  # fmt: skip
        try:
            ack = await asyncio.wait_for(direct.send_command(command), timeout_s)
        except (MavlinkDirectError, TimeoutError):
            return None
        return mav_result_name(int(json.loads(ack.fields_json).get("result", -1)))

    def _call(self, what: str, coro: Any) -> Any:
        """Run one MAVSDK request, translating its errors into companion.errors."""
        self._require_alive()
        timeout_s = self.cfg.command_timeout_s * (1 + self.cfg.command_retries) + 3.0
        try:
            return self._runner.run(coro, timeout_s)  # type: ignore[union-attr]
        except TimeoutError as exc:
            raise LinkTimeout(f"{what}: MAVSDK gave no answer within {timeout_s:.1f} s") from exc
        except Exception as exc:
            result = getattr(getattr(exc, "result", None), "name", None)
            if result is None:
                raise
            raise translate_result(what, result) from exc

    # ================================================================ setpoints
    def send_velocity_body(
        self, sp: VelocitySetpoint, echo_time_boot_ms: int | None = None
    ) -> None:
        """Body-frame velocity; ``echo_time_boot_ms`` is ignored (MAVSDK stamps setpoints)."""
        from mavsdk.plugins.offboard import VelocityBodyYawspeed

        self._limits.check_velocity(sp)
        _check_echo(echo_time_boot_ms)
        setpoint = VelocityBodyYawspeed(sp.forward_m_s, sp.right_m_s, sp.down_m_s,
                                        math.degrees(sp.yaw_rate_rad_s))  # fmt: skip
        self._call(
            "set_velocity_body", self._plugins_checked()["offboard"].set_velocity_body(setpoint)
        )
        self._offboard_ready = True
        self._counts["setpoints_sent"] += 1

    def send_position_ned(
        self,
        north_m: float,
        east_m: float,
        down_m: float,
        yaw_rad: float,
        echo_time_boot_ms: int | None = None,
    ) -> None:
        from mavsdk.plugins.offboard import PositionNedYaw

        self._limits.check_position(north_m, east_m, down_m, yaw_rad)
        _check_echo(echo_time_boot_ms)
        setpoint = PositionNedYaw(
            float(north_m), float(east_m), float(down_m), math.degrees(yaw_rad)
        )
        self._call(
            "set_position_ned", self._plugins_checked()["offboard"].set_position_ned(setpoint)
        )
        self._offboard_ready = True
        self._counts["setpoints_sent"] += 1

    # ================================================================ guards
    def _plugins_checked(self) -> dict[str, Any]:
        self._require_alive()
        return self._plugins

    def _require_alive(self) -> VehicleSnapshot:
        if self._closed:
            raise LinkLost("the link is closed; open a new one")
        snapshot = self._snapshot
        if snapshot is None or not self._plugins:
            raise LinkLost("no vehicle heard yet; call connect() first")
        if not self.link_alive():
            raise self._lost_error()
        return snapshot

    def _lost_error(self) -> LinkLost:
        return LinkLost(
            f"no telemetry from the vehicle for more than {self.cfg.link_lost_s} s on {self.url}; "
            "MAVSDK keeps listening and the link resumes by itself - hold, check the radio, retry"
        )


def _background(coro: Any) -> asyncio.Task[Any]:
    """A stream-following task whose failure is logged at once, not when it is collected."""
    task = asyncio.ensure_future(coro)

    def report(done: asyncio.Task[Any]) -> None:
        if not done.cancelled() and done.exception() is not None:
            log.error("MAVSDK stream task failed", exc_info=done.exception())

    task.add_done_callback(report)
    return task


async def _first_from(direct: Any, message_name: str, component_id: int) -> dict[str, Any]:
    """The fields of the first ``message_name`` that ``component_id`` sends."""
    async for message in direct.subscribe_message(message_name):
        if message.component_id == component_id:
            fields: dict[str, Any] = json.loads(message.fields_json)
            return fields
    raise LinkLost(f"MAVSDK ended the {message_name} subscription")


def _check_echo(echo_time_boot_ms: int | None) -> None:
    """Same argument checks as the pymavlink link, though MAVSDK cannot send the echo."""
    if echo_time_boot_ms is not None and not 0 <= int(echo_time_boot_ms) < 2**32:
        raise ValueError(f"echo_time_boot_ms {echo_time_boot_ms} is not a uint32 ms stamp")
