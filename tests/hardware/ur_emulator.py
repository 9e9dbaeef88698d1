"""A loopback UR controller that the real ur_rtde libraries connect to: dashboard, script ports and RTDE.

```
with URControllerEmulator(q0) as ctrl:                      # a child process on a private 127.x.y.z
    control = rtde_control.RTDEControlInterface(ctrl.host)   # dashboard, script upload, RTDE: all real
    control.moveJ(q, 0.5, 1.0)                                # integrated on the UR model, 500 Hz
    ctrl.snapshot()["q"]                                      # what the emulated arm did
```

Written from Universal Robots' public protocol descriptions (the RTDE guide, the dashboard server's
commands) and from what ur_rtde 1.6's control script expects of the controller (`ur_controller.py`), not from
any client's code. What is emulated:

- **Dashboard (29999)**: the greeting, ``PolyscopeVersion``, ``get serial number``, ``is in remote
  control``, ``running``, ``programState``, ``robotmode``, ``safetystatus``, ``stop``, ``unlock protective
  stop`` (refused for `unlock_delay_s` after the stop, as the real one refuses for 5 s), ``close safety
  popup``, ``power on``, ``brake release``, ``quit``; anything else: the real server's "could not understand".
- **Script ports (30001-30003)**: a program (a top-level ``def NAME(): ... end``) replaces the running one;
  ur_rtde's control script is recognised and its register protocol run by `EmulatedController`.
- **RTDE (30004)**: protocol version 2, the controller version (5.11: an e-Series arm, so ur_rtde runs at
  500 Hz), output recipes at the requested rate (at most 500 Hz), input recipes with per-register ownership
  (``IN_USE`` while another connection holds a register, as the controller answers), start / pause,
  data packages both ways with bit-exact big-endian doubles.
- **Faults**: a protective stop, an e-stop, a dropped link (every connection closed and new ones refused until
  `restore_link`, the controller itself running on), each now or `after_s` into the next motion; a slow
  cycle (RTDE exchanged only every `period_s`).

Not emulated faithfully (tests must not rely on these):

- The URScript program is not interpreted: only the command ids in `ur_controller.SUPPORTED_COMMANDS` run
  (movej, movej_ik, movel, movel_fk, servoj, servo_stop, stopj, stopl, set_tcp, is_steady, protective_stop,
  stop script); custom scripts are recorded, not run; the upper register range and the ExternalControl URCap
  path are absent; ``rtde_set_watchdog`` (ur_rtde's ``setWatchdog``) is not emulated.
- Motion is kinematic (see `ur_controller.py`): no dynamics, no joint-speed safety limits in movel, no
  blending, no controller servo filter (a first-order lag stands in); a safety stop halts the arm at once.
- The primary / secondary interfaces' own messages (robot state, version) are never sent: ur_rtde does not
  read them. ``stop`` answers "Stopped" even when nothing runs (ur_rtde sends it right after ending its own
  script and treats any other answer as an error; the real server's failure case is undocumented).
- Timing is soft real time (a Python thread): cycles slip under load; after more than 10 late cycles the
  controller drops the backlog, so its clock then runs slow rather than racing.
- A dropped link is a reset / refused connection; a real pulled cable is silence until TCP times out.
"""

from __future__ import annotations

import multiprocessing
import os
import random
import re
import socket
import struct
import threading
import time
from contextlib import suppress

from rtde_loopback import OUTPUT_TYPES, TYPE_FORMAT, _default_value, _recv_exact, _send
from ur_controller import CYCLE_S, EmulatedController

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORTS = (30001, 30002, 30003)
ALL_PORTS = (DASHBOARD_PORT, *SCRIPT_PORTS, RTDE_PORT)

#: the controller's software version as RTDE reports it (5.11: an e-Series arm, so ur_rtde runs at 500 Hz)
CONTROLLER_VERSION = (5, 11, 1, 108318)
POLYSCOPE_VERSION = "URSoftware 5.11.1.108318 (Mar 22 2021)"


def _input_types() -> dict[str, str]:
    types = {
        "input_bit_registers0_to_31": "UINT32",
        "input_bit_registers32_to_63": "UINT32",
        "standard_digital_output_mask": "UINT8",
        "standard_digital_output": "UINT8",
        "configurable_digital_output_mask": "UINT8",
        "configurable_digital_output": "UINT8",
        "tool_digital_output_mask": "UINT8",
        "tool_digital_output": "UINT8",
        "speed_slider_mask": "UINT32",
        "speed_slider_fraction": "DOUBLE",
        "standard_analog_output_mask": "UINT8",
        "standard_analog_output_type": "UINT8",
        "standard_analog_output_0": "DOUBLE",
        "standard_analog_output_1": "DOUBLE",
        "external_force_torque": "VECTOR6D",
    }
    for i in range(48):
        types[f"input_int_register_{i}"] = "INT32"
        types[f"input_double_register_{i}"] = "DOUBLE"
    for i in range(64, 128):
        types[f"input_bit_register_{i}"] = "BOOL"
    return types


INPUT_TYPES = _input_types()
_OUTPUT_TYPES = {**OUTPUT_TYPES, "runtime_state": "UINT32", "robot_status_bits": "UINT32"}


def _pack(rtde_type: str, value) -> bytes:
    values = tuple(value) if isinstance(value, (list, tuple)) else (value,)
    return struct.pack(">" + TYPE_FORMAT[rtde_type], *values)


class _RtdeClient:
    """One RTDE client connection."""

    def __init__(self, server: _Emulator, conn: socket.socket, cid: int):
        self.server, self.conn, self.cid = server, conn, cid
        self.ctrl = server.ctrl
        self.output_recipe: list[tuple[str, str]] = []
        self.input_recipes: dict[int, list[tuple[str, str]]] = {}
        self.period_s = 1.0 / 500.0
        self.started = False
        self.t_sent = 0.0
        self.send_lock = threading.Lock()

    def send(self, ptype: int, payload: bytes = b"") -> None:
        with self.send_lock:
            _send(self.conn, ptype, payload)

    def publish(self, outputs: dict, t_now: float) -> None:
        """Send one data package if this client's period has passed (called from the controller loop)."""
        if not self.started or t_now - self.t_sent < self.period_s - 0.5 * CYCLE_S:
            return
        self.t_sent = t_now
        # Fields the emulation does not model (currents, temperatures, ...) stream zeros.
        body = b"".join(_pack(t, outputs.get(n, _default_value(t))) for n, t in self.output_recipe)
        try:
            self.send(ord("U"), struct.pack(">B", 1) + body)
        except OSError:
            self.server.close_conn(self.conn)

    def handle(self) -> None:
        try:
            while True:
                size, ptype = struct.unpack(">HB", _recv_exact(self.conn, 3))
                self._dispatch(chr(ptype), _recv_exact(self.conn, size - 3))
        except (ConnectionError, OSError, struct.error, ValueError):
            pass
        finally:
            self.started = False
            self.ctrl.release_inputs(self.cid)
            self.server.close_conn(self.conn)

    def _dispatch(self, kind: str, payload: bytes) -> None:
        if kind == "V":  # request protocol version: we speak version 2
            (version,) = struct.unpack(">H", payload)
            self.send(ord("V"), struct.pack(">B", int(version == 2)))
        elif kind == "v":
            self.send(ord("v"), struct.pack(">IIII", *CONTROLLER_VERSION))
        elif kind == "O":
            (frequency_hz,) = struct.unpack(">d", payload[:8])
            # The controller clamps the rate to its own cycle; <= 0 means "the controller's rate".
            self.period_s = 1.0 / (min(frequency_hz, 500.0) if frequency_hz > 0 else 500.0)
            names = [n for n in payload[8:].decode().split(",") if n]
            types = [_OUTPUT_TYPES.get(n, "NOT_FOUND") for n in names]
            ok = "NOT_FOUND" not in types
            self.output_recipe = list(zip(names, types)) if ok else []
            self.send(ord("O"), struct.pack(">B", 1 if ok else 0) + ",".join(types).encode())
        elif kind == "I":
            names = [n for n in payload.decode().split(",") if n]
            types = [INPUT_TYPES.get(n, "NOT_FOUND") for n in names]
            free = self.ctrl.claim_inputs(self.cid, [n for n, t in zip(names, types) if t != "NOT_FOUND"])
            it = iter(free)
            types = [t if t == "NOT_FOUND" or next(it) else "IN_USE" for t in types]
            recipe_id = 0
            if "NOT_FOUND" not in types and "IN_USE" not in types:
                recipe_id = len(self.input_recipes) + 1  # ids count from 1 per connection
                self.input_recipes[recipe_id] = list(zip(names, types))
            self.send(ord("I"), struct.pack(">B", recipe_id) + ",".join(types).encode())
        elif kind == "S":
            self.started = True
            self.send(ord("S"), struct.pack(">B", 1))
        elif kind == "P":
            self.started = False
            self.send(ord("P"), struct.pack(">B", 1))
        elif kind == "U":
            recipe = self.input_recipes.get(payload[0])
            if recipe is None:
                return  # the controller ignores packages for an unknown recipe
            fmt = ">" + "".join(TYPE_FORMAT[t] for _, t in recipe)
            flat = struct.unpack(fmt, payload[1:])
            names, values, k = [], [], 0
            for name, t in recipe:
                n = int(TYPE_FORMAT[t][:-1]) if len(TYPE_FORMAT[t]) > 1 else 1
                names.append(name)
                values.append(flat[k] if n == 1 else flat[k : k + n])
                k += n
            self.ctrl.write_inputs(names, values)


class _Emulator:
    """The servers and the controller loop, in the child process."""

    def __init__(self, host: str, ctrl: EmulatedController):
        self.host, self.ctrl = host, ctrl
        self.lock = threading.Lock()
        self.listeners: list[socket.socket] = []
        self.conns: set[socket.socket] = set()
        self.clients: list[_RtdeClient] = []
        self.link_up = False
        self._cid = 0
        self.fault: tuple[str, float] | None = None
        self.connections: dict[int, int] = {p: 0 for p in ALL_PORTS}
        self.overruns = 0

    # ------------------------------------------------------------------------------------------ sockets
    def listen(self) -> None:
        with self.lock:
            for port in ALL_PORTS:
                srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                srv.bind((self.host, port))
                srv.listen(8)
                self.listeners.append(srv)
                threading.Thread(target=self._accept, args=(srv, port), daemon=True).start()
            self.link_up = True

    def drop_link(self) -> None:
        with self.lock:
            self.link_up = False
            # The controller frees a client's input registers when its connection ends; done here, not
            # when the reader thread notices, so that a client reconnecting at once finds them free.
            for client in self.clients:
                self.ctrl.release_inputs(client.cid)
            for s in [*self.listeners, *self.conns]:
                with suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)
                s.close()
            self.listeners, self.conns, self.clients = [], set(), []

    def close_conn(self, conn: socket.socket) -> None:
        with self.lock:
            self.conns.discard(conn)
            for client in self.clients:
                if client.conn is conn:
                    self.ctrl.release_inputs(client.cid)
            self.clients = [s for s in self.clients if s.conn is not conn]
        with suppress(OSError):
            conn.shutdown(socket.SHUT_RDWR)
        conn.close()

    def _accept(self, srv: socket.socket, port: int) -> None:
        while True:
            try:
                conn, _ = srv.accept()
            except OSError:
                return  # the listener was closed (link dropped)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self.lock:
                self.conns.add(conn)
                self.connections[port] += 1
            if port == RTDE_PORT:
                with self.lock:
                    self._cid += 1
                    client = _RtdeClient(self, conn, self._cid)
                    self.clients.append(client)
                target = client.handle
            elif port == DASHBOARD_PORT:
                target = lambda c=conn: self._dashboard(c)  # noqa: E731
            else:
                target = lambda c=conn: self._script(c)  # noqa: E731
            threading.Thread(target=target, daemon=True).start()

    # ------------------------------------------------------------------------------------------ dashboard
    def _dashboard(self, conn: socket.socket) -> None:
        f = conn.makefile("rb")
        try:
            conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
            for raw in f:
                line = raw.decode(errors="replace").strip()
                reply = self._dashboard_reply(line)
                conn.sendall(reply.encode() + b"\n")
                if line == "quit":
                    break
        except OSError:
            pass
        finally:
            f.close()
            self.close_conn(conn)

    def _dashboard_reply(self, line: str) -> str:
        c = self.ctrl
        snap = c.snapshot()
        running = snap["program"] is not None
        if line == "PolyscopeVersion":
            return POLYSCOPE_VERSION
        if line == "get serial number":
            return "20185500001"
        if line == "is in remote control":
            return "true"
        if line == "running":
            return f"Program running: {str(running).lower()}"
        if line == "programState":
            return ("PLAYING " if running else "STOPPED ") + "<unnamed>"
        if line == "robotmode":
            return "Robotmode: " + ("POWER_OFF" if snap["estop"] else "RUNNING")
        if line == "safetystatus":
            status = (
                "ROBOT_EMERGENCY_STOP"
                if snap["estop"]
                else "PROTECTIVE_STOP"
                if snap["protective"]
                else "NORMAL"
            )
            return "Safetystatus: " + status
        if line == "stop":
            # "Stopped" also when nothing runs: ur_rtde sends "stop" right after its own stopScript has ended
            # the program, and treats any other answer as an error (the guide lists "Failed to execute: stop"
            # without saying when; we never answer it).
            if running:
                c.stop_program("stopped from the dashboard")
            return "Stopped"
        if line == "unlock protective stop":
            if c.unlock_protective_stop():
                return "Protective stop releasing"
            return (
                "Cannot unlock protective stop until 5s after occurrence. Always inspect cause of protective "
                "stop before unlocking"
            )
        if line == "close safety popup":
            return "closing safety popup"
        if line == "power on":
            return "Powering on"
        if line == "brake release":
            return "Brake releasing"
        if line == "quit":
            return "Disconnected"
        return f"could not understand: '{line}'"

    # ------------------------------------------------------------------------------------------ scripts
    def _script(self, conn: socket.socket) -> None:
        buf = ""
        try:
            while True:
                chunk = conn.recv(65536)
                if not chunk:
                    return
                buf += chunk.decode(errors="replace")
                # A program is a top-level "def NAME():" closed by a top-level "end" line.
                while (m := re.search(r"^def \w+\(\):\n.*?^end[ \t]*$\n?", buf, re.S | re.M)) is not None:
                    self.ctrl.load_program(m.group(0))
                    buf = buf[m.end() :]
        except OSError:
            pass
        finally:
            self.close_conn(conn)

    # ------------------------------------------------------------------------------------------ loop
    def run_loop(self, stop: threading.Event) -> None:
        """The controller's real-time loop, soft: a cycle every 2 ms of wall time."""
        t_next = time.monotonic()
        t_exchange = 0.0
        while not stop.is_set():
            t_next += CYCLE_S
            delay = t_next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -10 * CYCLE_S:  # overrun: drop the backlog instead of racing to catch up
                self.overruns += 1
                t_next = time.monotonic()
            now = time.monotonic()
            self._fire_fault()
            exchange = now - t_exchange >= self.ctrl.io_period_s - 0.5 * CYCLE_S
            self.ctrl.cycle(CYCLE_S, exchange)
            if exchange and self.link_up:
                t_exchange = now
                outputs = self.ctrl.outputs()
                with self.lock:
                    clients = list(self.clients)
                for s in clients:
                    s.publish(outputs, now)

    def _fire_fault(self) -> None:
        if self.fault is None:
            return
        kind, after_s = self.fault
        with self.ctrl.lock:
            t_motion = self.ctrl.motion_time_s()
        if t_motion is not None and t_motion >= after_s:
            self.fault = None
            self.apply(kind)

    def apply(self, kind: str) -> None:
        if kind == "protective_stop":
            self.ctrl.trigger_protective_stop()
        elif kind == "emergency_stop":
            self.ctrl.trigger_emergency_stop()
        elif kind == "drop_link":
            self.ctrl.note_fault(kind)
            self.drop_link()
        else:
            raise ValueError(f"unknown fault {kind!r}; known: protective_stop, emergency_stop, drop_link")


def _serve(host: str, q0, robot: str, unlock_delay_s: float, pipe) -> None:
    """Child-process entry: serve until the parent says "exit" or goes away."""
    ctrl = EmulatedController(robot, q0, unlock_delay_s=unlock_delay_s)
    emu = _Emulator(host, ctrl)
    emu.listen()
    stop = threading.Event()
    threading.Thread(target=emu.run_loop, args=(stop,), daemon=True).start()
    pipe.send(("ready", None))
    while True:
        try:
            name, args = pipe.recv()
        except (EOFError, OSError):
            break
        try:
            if name == "exit":
                break
            if name == "snapshot":
                result = {**ctrl.snapshot(), "connections": dict(emu.connections), "overruns": emu.overruns}
            elif name == "fault":
                kind, after_s = args
                if after_s is None:
                    emu.apply(kind)
                else:
                    emu.fault = (kind, after_s)
                result = None
            elif name == "restore_link":
                emu.listen()
                result = None
            elif name == "slow_cycle":
                ctrl.io_period_s = max(CYCLE_S, float(args[0]))
                result = None
            elif name == "reset":
                emu.fault = None
                if not emu.link_up:
                    emu.listen()
                ctrl.reset(args[0])
                emu.connections = {p: 0 for p in ALL_PORTS}
                result = None
            elif name == "release_emergency_stop":
                ctrl.release_emergency_stop()
                result = None
            elif name == "unlock_protective_stop":
                result = ctrl.unlock_protective_stop()
            else:
                raise ValueError(f"unknown request {name!r}")
            pipe.send(("ok", result))
        except Exception as exc:  # report to the test instead of dying silently
            pipe.send(("error", f"{type(exc).__name__}: {exc}"))
    stop.set()
    emu.drop_link()


def free_loopback_host(ports=ALL_PORTS) -> str:
    """A 127.x.y.z address where every controller port is free (parallel test runs do not collide)."""
    rng = random.Random(os.getpid() ^ time.monotonic_ns())
    for _ in range(50):
        host = f"127.{rng.randint(1, 254)}.{rng.randint(1, 254)}.{rng.randint(1, 254)}"
        socks = []
        try:
            for port in ports:
                s = socket.socket()
                socks.append(s)
                s.bind((host, port))
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
        return host
    raise RuntimeError("no free loopback address for the UR controller ports")


class URControllerEmulator:
    """The emulated controller in a child process (spawned: ur_rtde holds the GIL while it waits for data,
    so the server cannot share the test's interpreter). Use as a context manager.

    Args:
        q0: (6,) start joints [rad].
        robot: the UR model's registry name.
        unlock_delay_s: the dashboard refuses ``unlock protective stop`` this long after the stop.
    """

    def __init__(self, q0, robot: str = "ur5e", unlock_delay_s: float = 0.2, start_timeout_s: float = 60.0):
        ctx = multiprocessing.get_context("spawn")
        self.host = free_loopback_host()
        self._pipe, child = ctx.Pipe()
        self._lock = threading.Lock()
        self.process = ctx.Process(
            target=_serve, args=(self.host, list(map(float, q0)), robot, unlock_delay_s, child), daemon=True
        )
        self.process.start()
        if not self._pipe.poll(start_timeout_s):
            self.close()
            raise RuntimeError("the UR controller emulator did not start")
        self._pipe.recv()

    def _call(self, name: str, *args):
        with self._lock:
            self._pipe.send((name, args))
            if not self._pipe.poll(10.0):
                raise RuntimeError(f"the UR controller emulator did not answer {name!r}")
            status, result = self._pipe.recv()
        if status != "ok":
            raise RuntimeError(f"emulator: {result}")
        return result

    def snapshot(self) -> dict:
        """q (6,), flags, the commands its script took (`ReceivedCommand`), connection counts per port."""
        return self._call("snapshot")

    def fault(self, kind: str, after_s: float | None = None) -> None:
        """Inject `kind` ("protective_stop", "emergency_stop", "drop_link") now, or `after_s` into the next
        motion command (a move, a stop ramp or a servo stream)."""
        self._call("fault", kind, after_s)

    def restore_link(self) -> None:
        self._call("restore_link")

    def slow_cycle(self, period_s: float) -> None:
        """Exchange RTDE packages only every `period_s` (CYCLE_S restores the normal cycle)."""
        self._call("slow_cycle", period_s)

    def reset(self, q0) -> None:
        """A powered arm at `q0`, no program, no fault, link up, empty logs (tests sharing one emulator)."""
        self._call("reset", list(map(float, q0)))

    def release_emergency_stop(self) -> None:
        """The pendant's part: e-stop released, arm powered on, brakes released."""
        self._call("release_emergency_stop")

    def unlock_protective_stop(self) -> bool:
        """The pendant's "unlock" (refused, False, within `unlock_delay_s` of the stop)."""
        return self._call("unlock_protective_stop")

    def close(self) -> None:
        with suppress(OSError, BrokenPipeError):
            self._pipe.send(("exit", ()))
        self.process.join(5)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(5)

    def __enter__(self) -> URControllerEmulator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
