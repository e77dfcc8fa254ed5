"""Handshake helpers: build the HELLO, check the device's HELLO_ACK."""

from __future__ import annotations

import secrets

from .messages import PROTOCOL_VERSION, SCHEMA_HASH, Hello, HelloAck


class HandshakeError(RuntimeError):
    """The device answered with a different protocol version, schema or nonce."""


def make_hello(nonce: int | None = None) -> Hello:
    """HELLO carrying this host's protocol version and schema hash (random nonce by default)."""
    return Hello(PROTOCOL_VERSION, SCHEMA_HASH, secrets.randbits(32) if nonce is None else nonce)


def verify_hello_ack(ack: HelloAck, hello: Hello) -> None:
    """Raise HandshakeError unless ``ack`` answers ``hello`` with the same version and schema."""
    if ack.protocol_version != hello.protocol_version:
        host, dev = hello.protocol_version, ack.protocol_version
        raise HandshakeError(f"protocol version mismatch: host {host}, device {dev}")
    if ack.schema_hash != hello.schema_hash:
        raise HandshakeError(
            f"schema hash mismatch: host {hello.schema_hash:#010x}, device {ack.schema_hash:#010x} "
            f"(firmware {ack.fw_major}.{ack.fw_minor}.{ack.fw_patch} built against other definitions)"
        )
    if ack.nonce != hello.nonce:
        raise HandshakeError(f"HELLO_ACK nonce {ack.nonce:#010x} != HELLO nonce {hello.nonce:#010x}")
