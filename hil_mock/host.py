"""A minimal protocol host over pyserial, for tests and benchmarks of the mock (not the daemon)."""

from __future__ import annotations

import time
from collections import deque

import serial

from firmware_protocol import (
    Config,
    Hello,
    HelloAck,
    Message,
    Sample,
    Status,
    Stop,
    StreamDecoder,
    actuator_to_counts,
    encode,
    encode_command,
    make_hello,
    verify_hello_ack,
)

HELLO_RETRY_S = 0.1  # PROTOCOL.md §5: the host retries HELLO every 100 ms


class MiniHost:
    """Open ``port`` with pyserial, handshake, read messages, answer SAMPLEs."""

    def __init__(self, port: str, timeout: float = 0.05) -> None:
        self.ser = serial.Serial(port, timeout=timeout)
        self.decoder = StreamDecoder()
        self.pending: deque[Message] = deque()
        self.ack: HelloAck | None = None
        self.statuses: list[Status] = []

    def close(self) -> None:
        self.ser.close()

    def __enter__(self) -> MiniHost:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def send(self, msg: Hello | Config | Stop) -> None:
        self.ser.write(encode(msg))

    def command(self, seq: int, u: float, flags: int) -> None:
        """COMMAND answering SAMPLE ``seq`` with the physical command ``u`` (N m or V)."""
        assert self.ack is not None, "handshake first"
        self.ser.write(encode_command(self.ack.nonce, seq, actuator_to_counts(u, self.ack.actuator_full_scale), flags))

    def poll(self) -> list[Message]:
        """Messages that arrived (waits up to the port timeout for the first byte)."""
        data = self.ser.read(max(1, self.ser.in_waiting))
        msgs = self.decoder.feed(data) if data else []
        self.statuses += [m for m in msgs if type(m) is Status]
        return msgs

    def next_message(self, timeout: float = 1.0) -> Message | None:
        end = time.monotonic() + timeout
        while not self.pending:
            if time.monotonic() > end:
                return None
            self.pending.extend(self.poll())
        return self.pending.popleft()

    def next_sample(self, timeout: float = 1.0) -> Sample | None:
        end = time.monotonic() + timeout
        while (remaining := end - time.monotonic()) > 0:
            msg = self.next_message(remaining)
            if type(msg) is Sample:
                return msg
        return None

    def newest_sample(self, timeout: float = 1.0) -> Sample | None:
        """The newest SAMPLE: everything already received is read and the older SAMPLEs dropped (a host that fell
        behind answers the device's present tick, as the daemon does, not a backlog the device would discard)."""
        s = self.next_sample(timeout)
        if s is None:
            return None
        if self.ser.in_waiting:
            self.pending.extend(self.poll())
        newer = [m for m in self.pending if type(m) is Sample]
        others = [m for m in self.pending if type(m) is not Sample]
        self.pending.clear()
        self.pending.extend(others)
        return newer[-1] if newer else s  # type: ignore[return-value]

    def handshake(self, timeout: float = 5.0, hello: Hello | None = None, verify: bool = True) -> HelloAck:
        """HELLO (retried every 100 ms) until the matching HELLO_ACK; verified unless ``verify`` is False."""
        hello = hello or make_hello()
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.ser.write(b"\x00" + encode(hello))
            retry = time.monotonic() + HELLO_RETRY_S
            while time.monotonic() < retry:
                msg = self.next_message(retry - time.monotonic())
                if type(msg) is HelloAck and msg.nonce == hello.nonce:
                    if verify:
                        verify_hello_ack(msg, hello)
                    self.ack = msg
                    return msg
        raise TimeoutError(f"no HELLO_ACK from {self.ser.port} within {timeout:g} s")
