"""The live view's front door: one listening port for both names of the Foxglove WebSocket protocol.

The foxglove-sdk server accepts only the subprotocol ``foxglove.sdk.v1``; Lichtblick, older Foxglove builds and the
official ``@foxglove/ws-protocol`` client library ask for ``foxglove.websocket.v1`` and got HTTP 400. The two names
are one protocol (the sdk renamed it; the messages are identical), so the door takes the user's port, answers the
WebSocket handshake under the name the client asked for, and passes the bytes through to the sdk server on a private
loopback port. A client offering neither name gets a 400 naming both, and the run says so in one line.
"""

from __future__ import annotations

import contextlib
import socket
import sys
import threading
from collections.abc import Callable

SDK_SUBPROTOCOL = "foxglove.sdk.v1"
SUBPROTOCOLS = (SDK_SUBPROTOCOL, "foxglove.websocket.v1")
CLIENTS = "Foxglove, Lichtblick, @foxglove/ws-protocol clients"
_HEADER = b"sec-websocket-protocol"
_MAX_HEAD = 16384


def _say(message: str) -> None:
    print(f"furuta-rt: {message}", file=sys.stderr, flush=True)


def _read_head(sock: socket.socket) -> tuple[bytes, bytes]:
    """An HTTP head (up to and with the blank line) and whatever bytes came after it."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(4096)
        if not chunk or len(data) > _MAX_HEAD:
            raise ConnectionError("no HTTP head")
        data += chunk
    end = data.index(b"\r\n\r\n") + 4
    return data[:end], data[end:]


def offered_subprotocols(head: bytes) -> list[str]:
    """The subprotocol names a WebSocket handshake request offers, in its order."""
    names: list[str] = []
    for line in head.split(b"\r\n")[1:]:
        key, _, value = line.partition(b":")
        if key.strip().lower() == _HEADER:
            names += [n.strip() for n in value.decode("latin-1").split(",") if n.strip()]
    return names


def rename_subprotocol(head: bytes, name: str) -> bytes:
    """``head`` with its Sec-WebSocket-Protocol header(s) replaced by one naming ``name``."""
    lines = [line for line in head[:-4].split(b"\r\n") if line.partition(b":")[0].strip().lower() != _HEADER]
    return b"\r\n".join([*lines, b"Sec-WebSocket-Protocol: " + name.encode()]) + b"\r\n\r\n"


class SubprotocolDoor:
    """Listen on ``(host, port)``; pass each connection to the sdk server on ``inner_port`` (loopback)."""

    def __init__(self, host: str, port: int, inner_port: int, say: Callable[[str], None] = _say) -> None:
        self.inner_port = inner_port
        self.say = say
        self._refused: set[tuple[str, ...]] = set()
        family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
        self.sock = socket.create_server((host, port), family=family, backlog=16)
        self.port = self.sock.getsockname()[1]
        self._closed = False
        threading.Thread(target=self._accept, name="live-door", daemon=True).start()

    def close(self) -> None:
        self._closed = True
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()

    def _accept(self) -> None:
        while not self._closed:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            threading.Thread(target=self._serve, args=(conn,), name="live-client", daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        upstream = None
        try:
            conn.settimeout(10)
            head, rest = _read_head(conn)
            offered = offered_subprotocols(head)
            asked = next((n for n in SUBPROTOCOLS if n in offered), None)
            if asked is None:
                self._refuse(conn, offered)
                return
            upstream = socket.create_connection(("127.0.0.1", self.inner_port), timeout=10)
            upstream.sendall(rename_subprotocol(head, SDK_SUBPROTOCOL) + rest)
            answer, rest = _read_head(upstream)
            if asked != SDK_SUBPROTOCOL and offered_subprotocols(answer) == [SDK_SUBPROTOCOL]:
                answer = rename_subprotocol(answer, asked)
            conn.sendall(answer + rest)
            for s in (conn, upstream):
                s.settimeout(None)
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            back = threading.Thread(target=_pipe, args=(upstream, conn), name="live-pipe", daemon=True)
            back.start()
            _pipe(conn, upstream)
            back.join()
        except OSError:  # a client that drops its connection is not the run's problem
            pass
        finally:
            for s in (conn, upstream):
                if s is not None:
                    s.close()

    def _refuse(self, conn: socket.socket, offered: list[str]) -> None:
        what = ", ".join(offered) if offered else "no WebSocket subprotocol"
        body = (f"furuta-rt live view: a Foxglove WebSocket server; it speaks {' and '.join(SUBPROTOCOLS)} "
                f"({CLIENTS}); this request offered {what}\n").encode()
        conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain; charset=utf-8\r\n"
                     b"Content-Length: %d\r\nConnection: close\r\n\r\n" % len(body) + body)
        key = tuple(offered)
        if key not in self._refused:  # once per kind of client, not once per retry
            self._refused.add(key)
            self.say(f"live view: refused a client offering {what}; it speaks {' and '.join(SUBPROTOCOLS)} ({CLIENTS})")


def _pipe(src: socket.socket, dst: socket.socket) -> None:
    """Copy ``src`` to ``dst`` until ``src`` ends, then end ``dst``'s sending side."""
    try:
        while chunk := src.recv(65536):
            dst.sendall(chunk)
    except OSError:
        pass
    finally:
        with contextlib.suppress(OSError):
            dst.shutdown(socket.SHUT_WR)
