"""Messages and flags between the control process and its spawned children (logger, dashboard), on pipes.

multiprocessing's Queue and Event under the 'spawn' start method are built on named POSIX semaphores
(/dev/shm/sem.mp-*, 13 per run with a log). Only the resource tracker removes them when a process dies
unclean, and a SIGKILL of the whole process group kills the tracker too: the names stay in /dev/shm for
good. A pipe has no name; the kernel frees it with its last holder, whatever kills the processes.

``Channel``: one writer (this process), one reader (the child). ``put_nowait`` never blocks the control
loop: items wait in a bounded in-process queue (``queue.Full`` beyond ``maxsize``) and a feeder thread
moves them into the pipe, as multiprocessing.Queue's feeder does. When the process holding the write end
dies, the child's ``get`` raises EOFError. ``Flag``: an Event set in the child, read in the parent.
"""

from __future__ import annotations

import queue
import threading
from multiprocessing.connection import Connection, Pipe
from typing import Any


class Channel:
    """A bounded one-way queue to a spawned child; pickled into the child it carries the read end only."""

    def __init__(self, maxsize: int) -> None:
        self._reader, self._writer = Pipe(duplex=False)
        self._items: queue.Queue[Any] = queue.Queue(maxsize)
        self._feeder: threading.Thread | None = None

    def __getstate__(self) -> dict[str, Any]:
        return {"_reader": self._reader}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self._reader = state["_reader"]

    # ---------------------------------------------------------------- writer (this process)
    def put_nowait(self, item: Any) -> None:
        """Queue ``item``; queue.Full when ``maxsize`` items are still waiting for the pipe."""
        self._start()
        self._items.put_nowait(item)

    def put(self, item: Any, timeout: float | None = None) -> None:
        self._start()
        self._items.put(item, timeout=timeout)

    def cancel_join_thread(self) -> None:
        """Nothing to join: the feeder is a daemon thread (multiprocessing.Queue's name, kept for callers)."""

    def _start(self) -> None:
        if self._feeder is None:
            self._feeder = threading.Thread(target=self._feed, name="channel feeder", daemon=True)
            self._feeder.start()

    def _feed(self) -> None:
        items, writer = self._items, self._writer
        while True:
            item = items.get()
            try:
                writer.send(item)
            except OSError:  # the reader is gone: what is put from now on fills the queue and is dropped
                return

    # ---------------------------------------------------------------- reader (the child)
    def get(self, timeout: float | None = None) -> Any:
        """The next item; queue.Empty after ``timeout`` s; EOFError once the writer's process is gone."""
        if not self._reader.poll(timeout):
            raise queue.Empty
        return self._reader.recv()


class Flag:
    """multiprocessing.Event's set/is_set/wait on a pipe: set in a child, read in the parent; ``set(note)`` can say
    why (the parent reads it as ``note`` once the flag is seen set)."""

    def __init__(self) -> None:
        self._r: Connection
        self._w: Connection
        self._r, self._w = Pipe(duplex=False)
        self._set = False
        self.note = ""

    def set(self, note: str = "") -> None:
        self._w.send_bytes(note.encode())

    def wait(self, timeout: float | None = None) -> bool:
        if not self._set and self._r.poll(timeout):
            self._set = True
            self.note = self._r.recv_bytes().decode(errors="replace")
        return self._set

    def is_set(self) -> bool:
        return self.wait(0)
