"""A Foxglove WebSocket protocol client for the live view's tests and bench: what Foxglove does
when it connects, written from the protocol (subprotocol `foxglove.sdk.v1`: foxglove-sdk 0.30's
server refuses the older `foxglove.websocket.v1` name; the ops are the same): it reads the
server's `advertise` ops, subscribes to every channel and records each binary message-data frame
(opcode 0x01, subscription id u32 LE, log time u64 LE, payload) with its arrival time."""

from __future__ import annotations

import json
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect
from websockets.typing import Subprotocol

SUBPROTOCOL = Subprotocol("foxglove.sdk.v1")
MESSAGE_DATA = 0x01


def free_port() -> int:
    """A TCP port nothing listens on now (bound and released)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@dataclass
class Received:
    """What the client saw: the advertised channels by id, and (topic, log time ns, payload,
    arrival s since connecting) per message; `subscribed_at` the seconds until each topic's
    subscription went out."""

    channels: dict[int, dict[str, Any]] = field(default_factory=dict)
    messages: list[tuple[str, int, bytes, float]] = field(default_factory=list)
    subscribed_at: dict[str, float] = field(default_factory=dict)

    def topics(self) -> set[str]:
        return {channel["topic"] for channel in self.channels.values()}

    def of(self, topic: str) -> list[bytes]:
        return [payload for name, _, payload, _ in self.messages if name == topic]


class LiveClient:
    """Connects to ws://127.0.0.1:`port` on a thread (retrying until `timeout` s), subscribes
    to every channel as it is advertised and records what comes; `stop` ends it."""

    def __init__(self, port: int, timeout: float = 10.0) -> None:
        self.port = port
        self.received = Received()
        self._timeout = timeout
        self._stop = threading.Event()
        self.connected = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        deadline = time.monotonic() + self._timeout
        while True:
            try:
                socket_ = connect(f"ws://127.0.0.1:{self.port}", subprotocols=[SUBPROTOCOL], max_size=None)
                break
            except OSError:
                if time.monotonic() > deadline:
                    return
                time.sleep(0.02)
        start = time.perf_counter()
        self.connected.set()
        subscriptions: dict[int, str] = {}
        with socket_:
            while not self._stop.is_set():
                try:
                    frame = socket_.recv(timeout=0.05)
                except TimeoutError:
                    continue
                except ConnectionClosed:
                    return
                if isinstance(frame, str):
                    self._control(socket_, json.loads(frame), subscriptions, time.perf_counter() - start)
                elif frame[0] == MESSAGE_DATA:
                    sub, log_time = struct.unpack_from("<IQ", frame, 1)
                    self.received.messages.append(
                        (subscriptions[sub], log_time, bytes(frame[13:]), time.perf_counter() - start)
                    )

    def _control(self, socket_: Any, op: dict[str, Any], subscriptions: dict[int, str], now: float) -> None:
        """Subscribe to each advertised channel (subscription id = channel id)."""
        if op.get("op") != "advertise":
            return
        new = []
        for channel in op["channels"]:
            self.received.channels[channel["id"]] = channel
            subscriptions[channel["id"]] = channel["topic"]
            self.received.subscribed_at[channel["topic"]] = now
            new.append({"id": channel["id"], "channelId": channel["id"]})
        socket_.send(json.dumps({"op": "subscribe", "subscriptions": new}))

    def stop(self) -> Received:
        """Stop listening; what was received."""
        self._stop.set()
        self._thread.join(timeout=5)
        return self.received


def count_in_process(port: int, ready: Any, stop: Any, counts: Any) -> None:
    """A client in a process of its own (as Foxglove is), for the bench: sets `ready` once
    subscribed, records until `stop` is set, then puts {topic: messages} on the queue `counts`."""
    client = LiveClient(port)
    client.connected.wait(10)
    while not client.received.channels:
        time.sleep(0.01)
    time.sleep(0.1)
    ready.set()
    stop.wait()
    received = client.stop()
    tally: dict[str, int] = {}
    for topic, *_ in received.messages:
        tally[topic] = tally.get(topic, 0) + 1
    counts.put(tally)
