"""Issue 31 fault 8: `--executor ray --address 127.0.0.1:1` hung (ray.init retries an address forever). Now the
address is probed first (a TCP connection, then the gRPC handshake every Ray endpoint answers), each step bounded,
and a dead or foreign address is one error naming it; the invocation is marked failed, not left "running". No Ray
cluster, nor Ray itself, is needed: the probe runs before Ray is imported."""

from __future__ import annotations

import json
import socket
import threading
from pathlib import Path

import pytest
from conftest import require
from test_cli_errors import assert_refused, i2pbench
from test_report_html import KITTI

from i2pbench.errors import I2PBenchError
from i2pbench.runs.ray_executor import H2_PREFACE, check_address


def _closed_port() -> int:
    """A port nobody listens on: bound by us, then released."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _server(answer: bytes | None):
    """A one-connection server on a free port: reads the client's preface, then sends `answer` (None: stays silent
    until the test ends). Returns (port, stop)."""
    listener = socket.create_server(("127.0.0.1", 0))
    done = threading.Event()

    def serve():
        conn, _ = listener.accept()
        with conn:
            conn.recv(len(H2_PREFACE))
            if answer is not None:
                conn.sendall(answer)
            done.wait(30)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()

    def stop():
        done.set()
        thread.join(5)
        listener.close()

    return listener.getsockname()[1], stop


def test_run_with_a_ray_address_nobody_answers_at_is_one_error_and_the_invocation_says_failed(tmp_path):
    require(KITTI)
    address = f"127.0.0.1:{_closed_port()}"
    args = ["run", "--executor", "ray", "--address", address, "--dataset", "kitti", "--split", "all"]
    args += ["--data-root", str(KITTI), "--frames", "1", "--runs-dir", str(tmp_path / "runs")]
    done = i2pbench(*args, cwd=tmp_path)
    assert_refused(done, f"--address {address}: no Ray cluster there (Connection refused)", "ray start --head")
    (record,) = [json.loads(p.read_text()) for p in (tmp_path / "runs" / "kitti-all" / "invocations").iterdir()]
    assert record["status"] == "failed" and f"--address {address}" in record["error"]
    assert not list(Path(tmp_path / "runs" / "kitti-all" / "frames").glob("*.parquet"))


def test_a_port_that_accepts_but_never_answers_times_out_naming_the_address():
    port, stop = _server(None)
    try:
        with pytest.raises(
            I2PBenchError, match=rf"^--address 127\.0\.0\.1:{port}: no Ray cluster answered within 0.5 s"
        ):
            check_address(f"127.0.0.1:{port}", timeout_s=0.5)
    finally:
        stop()


def test_a_server_that_is_not_ray_is_named_as_such():
    port, stop = _server(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
    try:
        with pytest.raises(I2PBenchError, match=r"something listens there but does not answer as a Ray cluster"):
            check_address(f"ray://127.0.0.1:{port}")
    finally:
        stop()


def test_a_grpc_handshake_passes():
    port, stop = _server(bytes([0, 0, 0, 4, 0, 0, 0, 0, 0]))  # the empty SETTINGS frame a gRPC server sends first
    try:
        check_address(f"127.0.0.1:{port}")
    finally:
        stop()


@pytest.mark.parametrize("address", ["127.0.0.1:notaport", "127.0.0.1:70000", ":6379"])
def test_an_address_that_is_not_host_and_port_is_refused(address):
    with pytest.raises(I2PBenchError, match=r"expected HOST:PORT or ray://HOST:PORT"):
        check_address(address)


@pytest.mark.parametrize("address", [None, "auto", "local"])
def test_addresses_ray_resolves_itself_are_not_probed(address):
    check_address(address)  # nothing listens anywhere here; Ray itself says so (start() names the address)
