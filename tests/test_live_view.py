"""The live view (issue 18): `furuta-rt run --mock --foxglove=PORT` serves the run over the Foxglove
WebSocket protocol; a real WebSocket client (the `websockets` package, not the sdk) connects with the
protocol's subprotocol, subscribes as Foxglove does, and receives the joint states of the balancing
loop, on the log's one time base. The shipped layout is the one ``layout()`` builds and names only
topics and fields the run publishes."""

from __future__ import annotations

import asyncio
import json
import socket
import struct
import time
from typing import Any

import numpy as np
import pytest
import websockets
from test_reliability_harness import FURUTA_RT, DaemonProcess, traceback_free

from furuta_rt.io import log_schema as ls
from furuta_rt.runtime.live import LAYOUT_PATH, MAX_LIVE_HZ, layout

RATE = 500
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def _listen(port: int, topics: tuple[str, ...], seconds: float) -> dict[str, Any]:
    """Connect (retrying while the daemon starts), subscribe to ``topics``, collect messages for ``seconds``
    from the first one."""
    end_connect = time.monotonic() + 60
    while True:
        try:
            ws = await websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS, max_size=None)
            break
        except OSError:
            if time.monotonic() > end_connect:
                raise
            await asyncio.sleep(0.1)
    out: dict[str, Any] = {"subprotocol": ws.subprotocol, "channels": {}, "messages": {t: [] for t in topics}}
    subs: dict[int, str] = {}
    end = None
    async with ws:
        while end is None or time.monotonic() < end:
            try:
                msg = await asyncio.wait_for(ws.recv(), 1.0)
            except TimeoutError:
                continue
            if isinstance(msg, str):
                m = json.loads(msg)
                if m["op"] == "advertise":
                    out["channels"].update({c["topic"]: c for c in m["channels"]})
                    wanted = [c for c in m["channels"] if c["topic"] in topics]
                    subs.update({c["id"]: c["topic"] for c in wanted})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": c["id"], "channelId": c["id"]} for c in wanted]}))
            elif msg[0] == 0x01:  # MessageData: opcode, u32 subscription, u64 timestamp, payload
                _, sub, stamp = struct.unpack_from("<BIQ", msg)
                out["messages"][subs[sub]].append((stamp, time.time_ns(), json.loads(msg[13:])))
                if end is None:  # the device streams: count from here
                    end = time.monotonic() + seconds
    return out


@pytest.mark.hil
def test_a_websocket_client_receives_the_joint_states_of_a_mock_run() -> None:
    port = free_port()
    d = DaemonProcess(["--mock", "--duration", "4", "--no-tui", f"--foxglove={port}"])
    got = asyncio.run(_listen(port, (ls.JOINT_STATES_TOPIC, ls.TICK_TOPIC), 2.0))
    rc = d.wait(timeout=120)
    assert rc == 0 and traceback_free(d.stderr + d.stdout), d.stderr
    assert f"live view on ws://127.0.0.1:{port}" in d.stderr
    assert got["subprotocol"] in SUBPROTOCOLS
    ch = got["channels"]
    assert set(ch) == {ls.TICK_TOPIC, ls.JOINT_STATES_TOPIC, ls.TIMING_TOPIC, ls.EVENTS_TOPIC, ls.COMPENSATION_TOPIC}
    assert ch[ls.JOINT_STATES_TOPIC]["schemaName"] == "foxglove.JointStates" and ch[ls.JOINT_STATES_TOPIC]["encoding"] == "json"
    assert json.loads(ch[ls.TICK_TOPIC]["schema"]) == ls.TICK_SCHEMA
    joints = got["messages"][ls.JOINT_STATES_TOPIC]
    ticks = got["messages"][ls.TICK_TOPIC]
    every = round(RATE / MAX_LIVE_HZ)  # the live view sends every k-th tick (the log has them all)
    assert len(joints) > 0.7 * 2.0 * RATE / every, f"{len(joints)} joint states in 2 s at {RATE} Hz / {every}"
    seqs = sorted(b["seq"] for _, _, b in ticks)
    assert all(s % every == 0 for s in seqs) and min(set(np.diff(seqs))) == every
    for stamp, received, body in joints:
        assert [j["name"] for j in body["joints"]] == ["theta", "phi"]
        assert body["timestamp"]["sec"] * 1_000_000_000 + body["timestamp"]["nsec"] == stamp  # one time base
        assert 0 <= received - stamp < 2_000_000_000  # on the wall clock, live (not 1970, not late by seconds)
    # the loop was balancing: θ near upright, u the controller's (φ's effort), the tick's own values
    by_seq = {b["seq"]: b for _, _, b in ticks}
    balancing = [b for b in by_seq.values() if b["state"] == "balancing"]
    assert len(balancing) > 0.9 * len(by_seq) and max(abs(b["theta"]) for b in balancing) < 0.1
    tick_at = {stamp: body for stamp, _, body in ticks}
    same = [(body, tick_at[stamp]) for stamp, _, body in joints if stamp in tick_at]
    assert len(same) > 0.9 * len(joints)
    assert all(j["joints"][0]["position"] == t["theta"] and j["joints"][1]["effort"] == t["u"] for j, t in same)


def test_busy_port_is_one_line_exit_2() -> None:
    import subprocess

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        proc = subprocess.run([*FURUTA_RT, "run", "--mock", "--duration", "1", "--no-tui", f"--foxglove={port}"],
                              capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and traceback_free(proc.stderr)
    assert len(proc.stderr.strip().splitlines()) == 1 and f"--foxglove={port}" in proc.stderr, proc.stderr


def test_shipped_layout_is_the_built_one_and_names_what_the_run_publishes() -> None:
    shipped = json.loads(LAYOUT_PATH.read_text())
    assert shipped == layout(), "regenerate it: python -m furuta_rt.runtime.live"
    panels: list[dict] = []

    def walk(node: dict) -> None:
        if node.get("type") == "panel":
            panels.append(node)
        for item in node.get("items", []):
            walk(item["content"])

    walk(shipped["content"])
    kinds = [p["panelType"] for p in panels]
    assert kinds.count("Plot") == 3 and "StateTransitions" in kinds and "Log" in kinds
    plotted = [s["value"] for p in panels if p["panelType"] == "Plot" for s in p["config"]["paths"]]
    for field in ("theta", "phi", "u"):
        assert f"{ls.TICK_TOPIC}.{field}" in plotted
    for value in plotted:
        topic, field = value.rsplit(".", 1)
        assert topic == ls.TICK_TOPIC and field in ls.TICK_FIELDS
    log = next(p for p in panels if p["panelType"] == "Log")
    assert log["config"]["topicToRender"] == ls.EVENTS_TOPIC
