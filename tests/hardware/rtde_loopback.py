"""Loopback servers that speak the UR RTDE protocol (port 30004) and the Robotiq URCap socket (port 63352).

Written from the protocol description in Universal Robots' RTDE guide (every package: uint16 size including
the 3-byte header, uint8 type, then a big-endian payload), not from any client's code. They implement only
what a client needs to connect and read state:

- ``V`` request protocol version (uint16) -> uint8 accepted;
- ``v`` get URControl version -> 4 x uint32 (major, minor, bugfix, build);
- ``O`` setup outputs (double frequency [Hz], comma-separated names) -> uint8 recipe id, comma-separated
  types (``NOT_FOUND`` for a name the table below does not know);
- ``I`` setup inputs -> uint8 recipe id, types (every input is accepted as ``IN_USE``-free; the receive
  interface never sends inputs);
- ``S`` start -> uint8 accepted, then one ``U`` data package per period (recipe id, then the values);
- ``P`` pause -> uint8 accepted.

The robot state streamed is fixed at start-up (joint positions, TCP pose, safety bits), except that
``drop_after_s`` closes every connection that long after start, which is how a test cuts the cable.

ur_rtde's RTDEReceiveInterface holds the GIL while it waits for packages, so the server must run in another
process: `serve_rtde` is the target of a `multiprocessing` process (spawn context).
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from collections.abc import Sequence

# RTDE package types (the ASCII letters of the guide).
RTDE_REQUEST_PROTOCOL_VERSION = ord("V")
RTDE_GET_URCONTROL_VERSION = ord("v")
RTDE_TEXT_MESSAGE = ord("M")
RTDE_DATA_PACKAGE = ord("U")
RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS = ord("O")
RTDE_CONTROL_PACKAGE_SETUP_INPUTS = ord("I")
RTDE_CONTROL_PACKAGE_START = ord("S")
RTDE_CONTROL_PACKAGE_PAUSE = ord("P")

#: struct format of each RTDE type (big-endian, as on the wire).
TYPE_FORMAT = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}


def _output_types() -> dict[str, str]:
    """Output field -> RTDE type, from the guide's table (the fields a receive client is likely to ask)."""
    types = {
        "timestamp": "DOUBLE",
        "target_q": "VECTOR6D",
        "target_qd": "VECTOR6D",
        "target_qdd": "VECTOR6D",
        "target_current": "VECTOR6D",
        "target_moment": "VECTOR6D",
        "actual_q": "VECTOR6D",
        "actual_qd": "VECTOR6D",
        "actual_current": "VECTOR6D",
        "joint_control_output": "VECTOR6D",
        "actual_TCP_pose": "VECTOR6D",
        "actual_TCP_speed": "VECTOR6D",
        "actual_TCP_force": "VECTOR6D",
        "target_TCP_pose": "VECTOR6D",
        "target_TCP_speed": "VECTOR6D",
        "actual_digital_input_bits": "UINT64",
        "joint_temperatures": "VECTOR6D",
        "actual_execution_time": "DOUBLE",
        "robot_mode": "INT32",
        "joint_mode": "VECTOR6INT32",
        "safety_mode": "INT32",
        "safety_status": "INT32",
        "actual_tool_accelerometer": "VECTOR3D",
        "speed_scaling": "DOUBLE",
        "target_speed_fraction": "DOUBLE",
        "actual_momentum": "DOUBLE",
        "actual_main_voltage": "DOUBLE",
        "actual_robot_voltage": "DOUBLE",
        "actual_robot_current": "DOUBLE",
        "actual_joint_voltage": "VECTOR6D",
        "actual_digital_output_bits": "UINT64",
        "runtime_state": "UINT32",
        "robot_status_bits": "UINT32",
        "safety_status_bits": "UINT32",
        "standard_analog_input0": "DOUBLE",
        "standard_analog_input1": "DOUBLE",
        "standard_analog_output0": "DOUBLE",
        "standard_analog_output1": "DOUBLE",
        "ft_raw_wrench": "VECTOR6D",
        "payload": "DOUBLE",
        "payload_cog": "VECTOR3D",
        "payload_inertia": "VECTOR6D",
        "output_bit_registers0_to_31": "UINT32",
        "output_bit_registers32_to_63": "UINT32",
    }
    for i in range(48):
        types[f"output_int_register_{i}"] = "INT32"
        types[f"output_double_register_{i}"] = "DOUBLE"
    return types


OUTPUT_TYPES = _output_types()


def _send(conn: socket.socket, ptype: int, payload: bytes = b"") -> None:
    conn.sendall(struct.pack(">HB", 3 + len(payload), ptype) + payload)


def _recv_exact(conn: socket.socket, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = conn.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("client closed")
        buf += chunk
    return buf


def _default_value(rtde_type: str) -> tuple:
    fmt = TYPE_FORMAT[rtde_type]
    n = int(fmt[:-1]) if len(fmt) > 1 else 1
    zero = 0.0 if fmt[-1] == "d" else (False if fmt[-1] == "?" else 0)
    return (zero,) * n


class _RtdeClient:
    def __init__(self, conn: socket.socket, state: dict, deadline: float | None, version: Sequence[int]):
        self.conn = conn
        self.state = state
        self.deadline = deadline
        self.version = version
        self.recipe: list[tuple[str, str]] = []
        self.frequency_hz = 125.0
        self.streaming = threading.Event()
        self.closed = threading.Event()
        self.lock = threading.Lock()

    def send(self, ptype: int, payload: bytes = b"") -> None:
        with self.lock:
            _send(self.conn, ptype, payload)

    def _data_payload(self, t: float) -> bytes:
        out = [struct.pack(">B", 1)]
        for name, rtde_type in self.recipe:
            if name == "timestamp":
                value: tuple = (t,)
            elif name in self.state:
                v = self.state[name]
                value = tuple(v) if isinstance(v, (list, tuple)) else (v,)
            else:
                value = _default_value(rtde_type)
            out.append(struct.pack(">" + TYPE_FORMAT[rtde_type], *value))
        return b"".join(out)

    def stream(self) -> None:
        t0 = time.monotonic()
        while not self.closed.is_set():
            if self.deadline is not None and time.monotonic() > self.deadline:
                self.close()
                return
            if self.streaming.is_set():
                try:
                    self.send(RTDE_DATA_PACKAGE, self._data_payload(time.monotonic() - t0))
                except OSError:
                    self.close()
                    return
            time.sleep(1.0 / self.frequency_hz)

    def close(self) -> None:
        if not self.closed.is_set():
            self.closed.set()
            try:
                self.conn.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self.conn.close()

    def handle(self) -> None:
        threading.Thread(target=self.stream, daemon=True).start()
        try:
            while not self.closed.is_set():
                size, ptype = struct.unpack(">HB", _recv_exact(self.conn, 3))
                payload = _recv_exact(self.conn, size - 3)
                self.state.setdefault("_log", []).append(chr(ptype))
                if ptype == RTDE_REQUEST_PROTOCOL_VERSION:
                    self.send(ptype, struct.pack(">B", 1))
                elif ptype == RTDE_GET_URCONTROL_VERSION:
                    self.send(ptype, struct.pack(">IIII", *self.version))
                elif ptype == RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS:
                    (frequency_hz,) = struct.unpack(">d", payload[:8])
                    # the controller clamps the rate to its own (125 Hz on CB3, 500 on e-Series)
                    self.frequency_hz = min(frequency_hz, 500.0) if frequency_hz > 0 else 500.0
                    # clients may end the list with a comma; the controller ignores the empty name
                    names = [n for n in payload[8:].decode().split(",") if n]
                    types = [OUTPUT_TYPES.get(n, "NOT_FOUND") for n in names]
                    self.recipe = [(n, t) for n, t in zip(names, types) if t != "NOT_FOUND"]
                    self.state["_requested_outputs"] = names
                    self.send(ptype, struct.pack(">B", 1) + ",".join(types).encode())
                elif ptype == RTDE_CONTROL_PACKAGE_SETUP_INPUTS:
                    names = [n for n in payload.decode().split(",") if n]
                    self.send(ptype, struct.pack(">B", 2) + ",".join("INT32" for _ in names).encode())
                elif ptype == RTDE_CONTROL_PACKAGE_START:
                    self.streaming.set()
                    self.send(ptype, struct.pack(">B", 1))
                elif ptype == RTDE_CONTROL_PACKAGE_PAUSE:
                    self.streaming.clear()
                    self.send(ptype, struct.pack(">B", 1))
                # data packages from the client (inputs) are read and ignored
        except (ConnectionError, OSError, struct.error):
            pass
        finally:
            self.close()


def serve_rtde(
    host: str,
    state: dict,
    ready,
    drop_after_s: float | None = None,
    version: Sequence[int] = (5, 11, 0, 0),
    port: int = 30004,
) -> None:
    """Serve RTDE on (host, port) until the process is terminated; `ready.set()` once listening.

    `state` maps output field names to values (e.g. ``{"actual_q": [...6], "actual_TCP_pose": [...6]}``);
    fields not in it stream zeros. `drop_after_s` closes each connection that long after it was accepted.
    """
    srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind((host, port))
    srv.listen(8)
    ready.set()
    while True:
        conn, _ = srv.accept()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        deadline = None if drop_after_s is None else time.monotonic() + drop_after_s
        client = _RtdeClient(conn, state, deadline, version)
        threading.Thread(target=client.handle, daemon=True).start()
