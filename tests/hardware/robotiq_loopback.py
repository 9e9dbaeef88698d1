"""A loopback Robotiq URCap socket server (port 63352 protocol) with a simulated 2F gripper.

One text line per command: ``SET VAR n`` -> ``ack`` (several ``VAR n`` pairs in one SET are accepted, as the
URCap does), ``GET VAR`` -> ``VAR n``; anything else -> ``?``. The simulated gripper activates after a few
status polls, moves `step` position counts per poll towards its request once GTO is 1, and stops on an
object at `object_position` when closing past it (OBJ 2). `log` keeps every line received, in order.
Pure Python sockets: it runs in a thread of the test process.
"""

from __future__ import annotations

import socket
import threading


class RobotiqLoopback:
    def __init__(self, object_position: int | None = None, step: int = 60, activation_polls: int = 2):
        self.object_position = object_position
        self.step = step
        self.activation_polls = activation_polls
        self.vars = {"ACT": 0, "GTO": 0, "STA": 0, "POS": 0, "PRE": 0, "OBJ": 3, "SPE": 0, "FOR": 0, "FLT": 0}
        self.request = 0
        self.log: list[str] = []
        self.drop_on: str | None = None  # close the connection when this command arrives
        self.reply_override: dict[str, str] = {}
        self._sta_polls = 0
        self.holding = False
        self._srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._srv.bind(("127.0.0.1", 0))
        self._srv.listen(4)
        self.port = self._srv.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._srv.close()

    # --------------------------------------------------------------------------------------- simulation
    def _advance(self) -> None:
        v = self.vars
        if v["ACT"] == 1 and v["STA"] != 3:
            self._sta_polls += 1
            v["STA"] = 1 if self._sta_polls < self.activation_polls else 3
            return
        if v["STA"] != 3 or v["GTO"] != 1:
            return
        if v["PRE"] != self.request:  # a new request: the gripper takes it (and leaves the object)
            v["PRE"], self.holding = self.request, False
        if self.holding:  # stopped on an object; stays there until a new request
            return
        pos, target = v["POS"], self.request
        if pos == target:
            v["OBJ"] = 3
            return
        direction = 1 if target > pos else -1
        new = pos + direction * min(self.step, abs(target - pos))
        obj = self.object_position
        if obj is not None and direction > 0 and pos < obj <= new:
            v["POS"], v["OBJ"], self.holding = obj, 2, True
            return
        v["POS"] = new
        v["OBJ"] = 0 if new != target else 3

    def _handle(self, line: str) -> str | None:
        self.log.append(line)
        if self.drop_on is not None and line.startswith(self.drop_on):
            return None
        if line in self.reply_override:
            return self.reply_override[line]
        parts = line.split()
        if len(parts) >= 3 and parts[0] == "SET" and len(parts) % 2 == 1:
            for var, value in zip(parts[1::2], parts[2::2]):
                if var not in self.vars or not value.isdigit():
                    return "?"
                if var == "POS":
                    self.request = int(value)
                elif var in ("ACT", "GTO", "SPE", "FOR"):
                    self.vars[var] = int(value)
                else:
                    return "?"
            return "ack"
        if len(parts) == 2 and parts[0] == "GET" and parts[1] in self.vars:
            self._advance()
            return f"{parts[1]} {self.vars[parts[1]]}"
        return "?"

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._srv.accept()
            except OSError:
                return
            with conn:
                buf = b""
                while True:
                    try:
                        chunk = conn.recv(1024)
                    except OSError:
                        break
                    if not chunk:
                        break
                    buf += chunk
                    while b"\n" in buf:
                        raw, buf = buf.split(b"\n", 1)
                        reply = self._handle(raw.decode().strip())
                        if reply is None:
                            conn.shutdown(socket.SHUT_RDWR)
                            buf = b""
                            break
                        conn.sendall(reply.encode() + b"\n")
                    else:
                        continue
                    break
