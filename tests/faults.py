"""A fault proxy for object storage tests: an HTTP proxy on 127.0.0.1 in front of the moto server
that passes requests through, or stalls, resets, answers 500/503, truncates, corrupts or loses the
response of the requests a test picks.

One request per connection: the proxy reads the request (answering `Expect: 100-continue` itself),
forwards it with `Connection: close`, reads the whole answer, applies the fault, and closes. Clients
reconnect for each request, which every S3 client does anyway.
"""

from __future__ import annotations

import contextlib
import os
import socket
import threading
from collections.abc import Iterator
from dataclasses import dataclass

FAULTS = ("stall", "reset", "500", "503", "truncate", "corrupt", "lose")


@dataclass
class Rule:
    fault: str
    method: str | None = None  # GET, PUT, HEAD…; None: any
    path: str | None = None  # a substring of the request path; None: any
    count: int | None = None  # apply to this many matching requests, then pass; None: always
    after: int = 0  # let this many matching requests through first (a fault that starts part-way)
    hits: int = 0
    passed: int = 0

    def matches(self, method: str, path: str) -> bool:
        if self.count is not None and self.hits >= self.count:
            return False
        return (self.method is None or method == self.method) and (self.path is None or self.path in path)


class FaultProxy:
    def __init__(self, upstream_port: int):
        self.upstream = ("127.0.0.1", upstream_port)
        self.rules: list[Rule] = []
        self.seen: list[tuple[str, str, str]] = []  # (method, path, fault or "pass")
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._held: list[socket.socket] = []
        self._server = socket.socket()
        self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._server.bind(("127.0.0.1", 0))
        self._server.listen(64)
        self._server.settimeout(0.2)
        self.port = self._server.getsockname()[1]
        self.endpoint = f"http://127.0.0.1:{self.port}"
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def add(
        self, fault: str, method: str | None = None, path: str | None = None, count: int | None = None, after: int = 0
    ) -> Rule:
        assert fault in FAULTS, fault
        rule = Rule(fault, method, path, count, after)
        with self._lock:
            self.rules.append(rule)
        return rule

    def clear(self) -> None:
        with self._lock:
            self.rules.clear()
        self._release_held()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._server.close()
        self._release_held()

    def _release_held(self) -> None:
        with self._lock:
            held, self._held = self._held, []
        for conn in held:
            with contextlib.suppress(OSError):
                conn.close()

    # -- the proxy ---------------------------------------------------------------------------
    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            threading.Thread(target=self._handle, args=(conn,), daemon=True).start()

    def _rule_for(self, method: str, path: str) -> str | None:
        with self._lock:
            for rule in self.rules:
                if rule.matches(method, path):
                    if rule.passed < rule.after:
                        rule.passed += 1
                        continue
                    rule.hits += 1
                    self.seen.append((method, path, rule.fault))
                    return rule.fault
            self.seen.append((method, path, "pass"))
        return None

    def _handle(self, conn: socket.socket) -> None:
        conn.settimeout(60)
        try:
            head, body_start = _read_head(conn)
            if head is None:
                conn.close()
                return
            lines = head.split(b"\r\n")
            method, path, _ = lines[0].decode("latin-1").split(" ", 2)
            headers = [ln for ln in lines[1:] if ln]
            fault = self._rule_for(method, path)
            if fault == "stall":  # never answer, not even to Expect: 100-continue
                with self._lock:
                    self._held.append(conn)
                return
            if fault == "reset":
                conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
                conn.close()
                return
            if any(h.lower().startswith(b"expect:") for h in headers):
                conn.sendall(b"HTTP/1.1 100 Continue\r\n\r\n")
            body = _read_body(conn, headers, body_start)
            if fault in ("500", "503"):
                conn.sendall(_error_response(int(fault)))
                conn.close()
                return
            kept = [h for h in headers if not h.lower().startswith((b"connection:", b"expect:"))]
            request = lines[0] + b"\r\n" + b"\r\n".join([*kept, b"Connection: close"]) + b"\r\n\r\n" + body
            response = _exchange(self.upstream, request)
            if fault == "lose":  # the server did the work; the client never hears of it
                conn.close()
                return
            if fault == "truncate":
                response = response[: max(len(response) // 2, response.find(b"\r\n\r\n") + 5)]
            elif fault == "corrupt":
                split = response.find(b"\r\n\r\n") + 4
                if split < len(response):
                    middle = split + (len(response) - split) // 2
                    response = response[:middle] + bytes([response[middle] ^ 0x5A]) + response[middle + 1 :]
            conn.sendall(response)
            conn.close()
        except OSError:
            with contextlib.suppress(OSError):
                conn.close()


def _read_head(conn: socket.socket) -> tuple[bytes | None, bytes]:
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = conn.recv(65536)
        if not chunk:
            return None, b""
        data += chunk
    head, rest = data.split(b"\r\n\r\n", 1)
    return head, rest


def _header(headers: list[bytes], name: bytes) -> bytes | None:
    for h in headers:
        key, _, value = h.partition(b":")
        if key.strip().lower() == name:
            return value.strip()
    return None


def _read_body(conn: socket.socket, headers: list[bytes], start: bytes) -> bytes:
    length = _header(headers, b"content-length")
    if length is not None:
        body = start
        while len(body) < int(length):
            chunk = conn.recv(min(1 << 20, int(length) - len(body)))
            if not chunk:
                break
            body += chunk
        return body
    if (_header(headers, b"transfer-encoding") or b"").lower() == b"chunked":
        body = start
        while not body.endswith(b"0\r\n\r\n") and b"\r\n0\r\n\r\n" not in body:
            chunk = conn.recv(65536)
            if not chunk:
                break
            body += chunk
        return body
    return start


def _exchange(address: tuple[str, int], request: bytes) -> bytes:
    with socket.create_connection(address, timeout=60) as upstream:
        upstream.sendall(request)
        parts = []
        while chunk := upstream.recv(1 << 20):
            parts.append(chunk)
    return b"".join(parts)


def _error_response(status: int) -> bytes:
    reason = {500: "Internal Server Error", 503: "Slow Down"}[status]
    code = {500: "InternalError", 503: "SlowDown"}[status]
    body = f'<?xml version="1.0" encoding="UTF-8"?><Error><Code>{code}</Code><Message>{reason}</Message></Error>'
    head = f"HTTP/1.1 {status} {reason}\r\nContent-Type: application/xml\r\nContent-Length: {len(body)}\r\n"
    return (head + "Connection: close\r\n\r\n" + body).encode()


@contextlib.contextmanager
def fault_proxy(env: dict[str, str]) -> Iterator[tuple[FaultProxy, dict[str, str]]]:
    """A proxy in front of the moto server of `env`, and the client environment that goes through it."""
    from tests.servers import listeners

    upstream = int(env["AWS_ENDPOINT_URL"].rsplit(":", 1)[1])
    proxy = FaultProxy(upstream)
    bound = [address for address, pid in listeners() if pid == os.getpid()]
    assert bound and all(a == "127.0.0.1" for a in bound), bound  # the proxy (this process) on loopback only
    try:
        yield proxy, env | {"AWS_ENDPOINT_URL": proxy.endpoint}
    finally:
        proxy.close()
