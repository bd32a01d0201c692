"""MAVLink 2 signing at the companion: ``col fly --signing-key`` flies a signing SITL and its tlog
keeps working; a wrong key, a missing key and a bad key file are reported clearly."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from pymavlink import mavutil

from colcommon.signing import parse_key, read_key
from companion.config import LinkConfig
from companion.errors import ConfigError, LinkError
from companion.link.mavlink_link import MavlinkLink
from companion.simulator import running_sitl
from tests.conftest import free_port
from tests.test_fly_e2e import col_command

pytestmark = [pytest.mark.realtime, pytest.mark.e2e]

KEY_HEX = "5a" * 32
OTHER_HEX = "a5" * 32
SIGNED_FLAG = 0x01  # MAVLINK_IFLAG_SIGNED


def write_key(path: Path, hex_key: str) -> Path:
    path.write_text(hex_key + "\n")
    return path


def tlog_packets(path: Path) -> list[bytes]:
    """The raw packet of every record, as pymavlink's own tlog reader returns them."""
    log = mavutil.mavlink_connection(str(path), dialect="common")
    out = []
    while (msg := log.recv_match()) is not None:
        out.append(bytes(msg.get_msgbuf()))
    return out


def test_a_signed_companion_flies_a_signing_sitl_and_its_tlog_reads_back(tmp_path: Path) -> None:
    key = write_key(tmp_path / "k.hex", KEY_HEX)
    run_dir = tmp_path / "run"
    args = [*col_command(), "fly", "--pilot", "expert", "--episodes", "1", "--condition", "demo", "--no-learn",
            "--seed", "0", "--run-dir", str(run_dir), "--signing-key", str(key)]
    done = subprocess.run(args, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-3000:]
    assert '"successes": 1' in done.stdout.splitlines()[-1]
    packets = tlog_packets(run_dir / "session.tlog")
    assert len(packets) > 100
    signed = [p for p in packets if p[0] == 0xFD and p[2] & SIGNED_FLAG]
    assert len(signed) == len(packets)  # both directions signed, all of it logged and readable


def _link(key_file: str, port: int) -> MavlinkLink:
    return MavlinkLink(LinkConfig(connection=f"udpin:127.0.0.1:{port}", signing_key_file=key_file,
                                  request_rates_on_connect=False))


@pytest.mark.parametrize(("sitl_key", "ours", "says"), [
    (KEY_HEX, OTHER_HEX, "wrong MAVLink signing key"),
    (KEY_HEX, None, "the vehicle signs its MAVLink messages"),
    (None, KEY_HEX, "the vehicle does not sign its messages"),
], ids=["wrong-key", "no-key", "vehicle-unsigned"])
def test_mismatched_keys_are_reported_clearly(tmp_path: Path, sitl_key: str | None, ours: str | None, says: str) -> None:
    port = free_port()
    extra = ["--signing-key", str(write_key(tmp_path / "sitl.hex", sitl_key))] if sitl_key else []
    ours_file = str(write_key(tmp_path / "ours.hex", ours)) if ours else ""
    with running_sitl(port, clock="realtime", camera=False, extra_args=extra):
        link = _link(ours_file, port)
        try:
            with pytest.raises(LinkError, match=says):
                link.connect(timeout_s=10.0)
        finally:
            link.close()


def test_bad_key_files_are_explained(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="64 hex digits"):
        parse_key(b"not a key")
    with pytest.raises(ConfigError, match="all-zero"):
        parse_key(b"00" * 32)
    with pytest.raises(ConfigError, match="cannot read"):
        read_key(tmp_path / "missing.key")
    assert parse_key(bytes(range(32))) == bytes(range(32))  # 32 raw bytes work too
    assert parse_key(KEY_HEX.encode()) == bytes.fromhex(KEY_HEX)
    with pytest.raises(ConfigError, match="64 hex digits"):
        _link(str(write_key(tmp_path / "short.hex", "abcd")), free_port())


def test_the_mavsdk_link_refuses_a_signing_key_instead_of_flying_unsigned() -> None:
    from companion.link import open_link

    with pytest.raises(ConfigError, match="does not sign"):
        open_link(LinkConfig(signing_key_file="k.hex"), "mavsdk")
