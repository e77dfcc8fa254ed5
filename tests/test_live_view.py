"""The live view: `furuta-rt run --mock --foxglove=PORT` serves the run over the Foxglove WebSocket protocol under
both of its names. The official client library (`@foxglove/ws-protocol`, run by Node; subprotocol
foxglove.websocket.v1, as Lichtblick and older Foxglove builds) and a plain WebSocket client offering only
foxglove.sdk.v1 (the `websockets` package) subscribe at once and receive the joint states of the balancing loop, on
the log's one time base; a client offering neither name is refused with one line. The shipped layout is the one
``layout()`` builds and names only topics and fields the run publishes."""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import socket
import struct
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import websockets
from test_reliability_harness import FURUTA_RT, DaemonProcess, run_queue_wait_s, traceback_free

from furuta_rt.io import log_schema as ls
from furuta_rt.runtime.live import LAYOUT_PATH, MAX_LIVE_HZ, layout

RATE = 500
ROOT = Path(__file__).resolve().parents[1]
NODE_CLIENT = Path(__file__).with_name("live") / "foxglove_client.cjs"
NPM_DIR = ROOT / "build" / "npm-foxglove"  # the official client library, installed here by the test itself
NPM_PACKAGES = ("@foxglove/ws-protocol@0.8.0", "ws@8.23.0")


def official_client_modules() -> Path:
    """node_modules with @foxglove/ws-protocol (and `ws`, Node 20 has no WebSocket of its own), installed by npm."""
    modules = NPM_DIR / "node_modules"
    if (modules / "@foxglove" / "ws-protocol" / "package.json").exists() and (modules / "ws").exists():
        return modules
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node/npm are not installed: the official Foxglove client library (@foxglove/ws-protocol, npm) "
                    "cannot run here")
    NPM_DIR.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run(["npm", "install", "--prefix", str(NPM_DIR), "--no-audit", "--no-fund", "--no-save",
                           *NPM_PACKAGES], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"npm install {' '.join(NPM_PACKAGES)} failed:\n{proc.stderr[-2000:]}"
    return modules


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def _listen(port: int, topics: tuple[str, ...], seconds: float) -> dict[str, Any]:
    """Connect (retrying while the daemon starts), subscribe to ``topics``, collect messages until their stamps span
    ``seconds`` of the run's time (or the run ends): the run's clock, not how fast a loaded machine delivers them."""
    end_connect = time.monotonic() + 60
    while True:
        try:
            ws = await websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], max_size=None)
            break
        except OSError:
            if time.monotonic() > end_connect:
                raise
            await asyncio.sleep(0.1)
    out: dict[str, Any] = {"subprotocol": ws.subprotocol, "channels": {}, "messages": {t: [] for t in topics}}
    subs: dict[int, str] = {}
    first = last = 0
    async with ws:
        while not first or last - first < seconds * 1e9:
            try:
                msg = await asyncio.wait_for(ws.recv(), 60.0)
            except websockets.exceptions.ConnectionClosed:
                break  # the run ended
            if isinstance(msg, str):
                m = json.loads(msg)
                if m["op"] == "advertise":
                    out["channels"].update({c["topic"]: c for c in m["channels"]})
                    wanted = [c for c in m["channels"] if c["topic"] in topics]
                    subs.update({c["id"]: c["topic"] for c in wanted})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": c["id"], "channelId": c["id"]} for c in wanted]}))
            elif msg[0] == 0x01:  # MessageData: opcode, u32 subscription, u64 timestamp, payload
                _, sub, last = struct.unpack_from("<BIQ", msg)
                out["messages"][subs[sub]].append((last, time.time_ns(), json.loads(msg[13:])))
                first = first or last
    return out


def _span_s(stamps: list[int]) -> float:
    """The run time (s) a client's messages cover, from their stamps."""
    return (max(stamps) - min(stamps)) * 1e-9 if stamps else 0.0


@pytest.mark.hil
async def _refused(port: int) -> int:
    """The HTTP status a client offering neither name of the protocol gets."""
    end_connect = time.monotonic() + 60
    while True:
        try:
            async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=["foo.v1"]):
                return 101
        except websockets.exceptions.InvalidStatus as err:
            return err.response.status_code
        except OSError:
            if time.monotonic() > end_connect:
                raise
            await asyncio.sleep(0.1)


@pytest.mark.hil
def test_both_protocol_names_receive_the_joint_states_of_a_mock_run() -> None:
    modules = official_client_modules()
    port = free_port()
    d = DaemonProcess(["--mock", "--duration", "5", "--no-tui", f"--foxglove={port}"])
    official = subprocess.Popen(["node", str(NODE_CLIENT), f"ws://127.0.0.1:{port}", "2", ls.JOINT_STATES_TOPIC],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "NODE_PATH": str(modules)})

    async def both() -> tuple[dict[str, Any], int]:
        return await asyncio.gather(_listen(port, (ls.JOINT_STATES_TOPIC, ls.TICK_TOPIC), 2.0), _refused(port))

    def waited() -> float:  # run-queue wait of the path a message takes: the run's logger (the server), this client
        return sum(run_queue_wait_s(pid) for pid in d.spawned()) + run_queue_wait_s(os.getpid(), threading.get_native_id())

    waited_s = -waited()
    got, refused = asyncio.run(both())
    waited_s = max(0.0, waited_s + waited())  # 0 if the run ended meanwhile (its logger's count gone)
    out, err = official.communicate(timeout=120)
    rc = d.wait(timeout=120)
    assert rc == 0 and traceback_free(d.stderr + d.stdout), d.stderr
    assert f"live view on ws://127.0.0.1:{port}" in d.stderr
    assert "serves foxglove.sdk.v1 and foxglove.websocket.v1" in d.stderr
    # the official client library: foxglove.websocket.v1, every channel, joint states of the balancing loop
    assert official.returncode == 0, err
    fox = json.loads(out)
    assert fox["subprotocol"] == "foxglove.websocket.v1" and not fox["errors"], fox["errors"]
    assert ls.JOINT_STATES_TOPIC in fox["channels"] and ls.COMPENSATION_TOPIC in fox["channels"]
    fox_joints = fox["messages"][ls.JOINT_STATES_TOPIC]
    span = _span_s([int(stamp) for stamp, _, _ in fox_joints])  # of the run's time (2 s, less if the run ended)
    assert span > 1.0 and len(fox_joints) > 0.7 * span * MAX_LIVE_HZ, f"{len(fox_joints)} joint states in {span:.2f} s"
    for stamp, _, body in fox_joints:
        assert body["timestamp"]["sec"] * 1_000_000_000 + body["timestamp"]["nsec"] == int(stamp)
        assert [j["name"] for j in body["joints"]] == ["theta", "phi"] and abs(body["joints"][0]["position"]) < 0.1
    # a client offering neither name: 400, and the run says which clients work, once
    assert refused == 400
    said = [line for line in d.stderr.splitlines() if "refused a client offering foo.v1" in line]
    assert len(said) == 1 and "foxglove.websocket.v1" in said[0], d.stderr
    # the sdk's own name
    assert got["subprotocol"] == "foxglove.sdk.v1"
    ch = got["channels"]
    assert set(ch) == {ls.TICK_TOPIC, ls.JOINT_STATES_TOPIC, ls.TIMING_TOPIC, ls.EVENTS_TOPIC, ls.COMPENSATION_TOPIC}
    assert ch[ls.JOINT_STATES_TOPIC]["schemaName"] == "foxglove.JointStates" and ch[ls.JOINT_STATES_TOPIC]["encoding"] == "json"
    assert json.loads(ch[ls.TICK_TOPIC]["schema"]) == ls.TICK_SCHEMA
    joints = got["messages"][ls.JOINT_STATES_TOPIC]
    ticks = got["messages"][ls.TICK_TOPIC]
    every = round(RATE / MAX_LIVE_HZ)  # the live view sends every k-th tick (the log has them all)
    span = _span_s([stamp for stamp, _, _ in joints])
    assert span > 1.0 and len(joints) > 0.7 * span * RATE / every, (
        f"{len(joints)} joint states in {span:.2f} s at {RATE} Hz / {every}")
    seqs = sorted(b["seq"] for _, _, b in ticks)
    assert all(s % every == 0 for s in seqs) and min(set(np.diff(seqs))) == every
    stamps = sorted(stamp for stamp, _, _ in ticks)  # at most MAX_LIVE_HZ a second of the run's time
    assert (len(stamps) - 1) / ((stamps[-1] - stamps[0]) * 1e-9) <= MAX_LIVE_HZ * 1.005
    # on the wall clock (one time base: never ahead of it) and live: half the messages within a second, none later
    # than 2 s beyond the time a loaded machine kept this client or the run waiting for a CPU
    late = sorted((received - stamp) * 1e-9 for stamp, received, _ in joints)
    assert late[0] >= 0 and late[len(late) // 2] < 1.0 and late[-1] < 2.0 + waited_s, (late[::50], waited_s)
    for stamp, _, body in joints:
        assert [j["name"] for j in body["joints"]] == ["theta", "phi"]
        assert body["timestamp"]["sec"] * 1_000_000_000 + body["timestamp"]["nsec"] == stamp  # one time base
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


def test_a_live_view_for_other_computers_warns_that_it_is_unauthenticated() -> None:
    port = free_port()
    proc = subprocess.run([*FURUTA_RT, "run", "--mock", "--duration", "0.5", "--no-tui", f"--foxglove={port}",
                           "--foxglove-host", "0.0.0.0"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and traceback_free(proc.stderr), proc.stderr
    assert f"live view on ws://0.0.0.0:{port}" in proc.stderr
    warned = [line for line in proc.stderr.splitlines() if "not authenticated" in line]
    assert len(warned) == 1 and f"0.0.0.0:{port}" in warned[0], proc.stderr


def test_a_live_view_host_that_is_not_an_address_is_one_line() -> None:
    proc = subprocess.run([*FURUTA_RT, "run", "--mock", "--duration", "0.5", "--no-tui", "--foxglove",
                           "--foxglove-host", "no.such.host.invalid"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and traceback_free(proc.stderr)
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()] and "--foxglove-host no.such.host.invalid" in proc.stderr
