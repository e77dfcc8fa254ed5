"""The pseudo-terminal the mock serves on: a raw pty pair whose slave is the host's serial port."""

from __future__ import annotations

import fcntl
import os
import tty


def open_raw_pty() -> tuple[int, str]:
    """Open a pty pair, put the slave in raw mode at once, return (non-blocking master fd, slave path).

    The slave fd is closed again: the host opens the path like any serial device, and the master
    then sees EIO on read when the host closes it (how the device notices a hang-up). A cooked pty
    would echo the host's bytes back and eat control characters; raw mode is set before anyone can
    open the path, and the settings stay with the pty while the master is open.
    """
    master, slave = os.openpty()
    try:
        tty.setraw(slave)
        path = os.ttyname(slave)
    finally:
        os.close(slave)
    flags = fcntl.fcntl(master, fcntl.F_GETFL)
    fcntl.fcntl(master, fcntl.F_SETFL, flags | os.O_NONBLOCK)
    return master, path
