"""Nobody else in: every SITL server binds loopback by default; another address needs
--allow-remote and a control token, and the token is then required on every control request."""

from __future__ import annotations

import json
import subprocess
import sys
import threading

import pytest

from colcommon.configio import build
from colcommon.errors import ConfigError
from companion.errors import SimulatorError
from companion.simulator import SimulatorClient
from sitl.config import SitlConfig
from sitl.exposure import authorised, check_exposure, is_loopback
from sitl.server import SitlServer
from sitl.transports import UdpClient

TOKEN = "correct-horse-battery-staple"


def free_cfg(**network: object) -> SitlConfig:
    d = SitlConfig().model_dump()
    d["network"].update(udp_local_ports=(0,), udp_remote_ports=(9,), tcp_port=0, camera_port=0, control_port=0, **network)
    d["clock"]["mode"] = "lockstep"
    return build(SitlConfig, d, "test")


def test_loopback_is_recognised() -> None:
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.10") and not is_loopback("no-such-host.invalid")


def test_binding_beyond_loopback_needs_the_flag_and_a_token() -> None:
    check_exposure("127.0.0.1", False, None)
    with pytest.raises(ConfigError, match="--allow-remote"):
        check_exposure("0.0.0.0", False, TOKEN)
    with pytest.raises(ConfigError, match="control token"):
        check_exposure("0.0.0.0", True, None)
    with pytest.raises(ConfigError, match="control token"):
        check_exposure("0.0.0.0", True, "short")
    check_exposure("0.0.0.0", True, TOKEN)
    with pytest.raises(ConfigError, match="--allow-remote"):  # the library refuses too, before any socket
        SitlServer(free_cfg(host="0.0.0.0"))


def test_col_sitl_refuses_a_wide_host_without_the_flag() -> None:
    done = subprocess.run([sys.executable, "-m", "sitl", "--host", "0.0.0.0", "--no-camera", "--duration", "0.1"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "--allow-remote" in done.stderr and "READY" not in done.stdout


def test_every_server_binds_loopback_by_default() -> None:
    server = SitlServer(free_cfg())
    try:
        addrs = [c.sock.getsockname()[0] for c in server.clients if isinstance(c, UdpClient)]
        addrs.append(server.tcp_listener.getsockname()[0])  # type: ignore[union-attr]
        addrs.append(server.control_listener.getsockname()[0])
        assert server.camera is not None
        addrs.append(server.camera.server._listener.getsockname()[0])  # type: ignore[attr-defined]
        assert addrs and all(a == "127.0.0.1" for a in addrs), addrs
    finally:
        server.close()


def test_the_token_is_required_on_every_control_request() -> None:
    assert authorised(b'{"cmd": "info"}', None)
    assert not authorised(b'{"cmd": "info"}', TOKEN)
    assert not authorised(b'{"cmd": "info", "token": "wrong"}', TOKEN)
    assert not authorised(b"[1, 2]", TOKEN) and not authorised(b"\xff", TOKEN)
    assert authorised(json.dumps({"cmd": "info", "token": TOKEN}).encode(), TOKEN)
    cfg = free_cfg()
    server = SitlServer(cfg, control_token=TOKEN)  # a token on loopback is honoured too
    port = server.control_listener.getsockname()[1]
    thread = threading.Thread(target=server.serve, daemon=True)
    thread.start()
    try:
        anonymous = SimulatorClient("127.0.0.1", port)
        with pytest.raises(SimulatorError, match="unauthorised"):
            anonymous.reset(seed=1)
        anonymous.close()
        ok = SimulatorClient("127.0.0.1", port, token=TOKEN)
        try:
            assert ok.reset(seed=1)["ok"] and ok.truth()["episode"] >= 1
        finally:
            ok.close()
    finally:
        server.stop()
        thread.join(10)
