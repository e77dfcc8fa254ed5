"""PROTOCOL.md §6, command acceptance: the one implementation of the rule.

The device model (hil_mock.firmware), every test device and the host's shutdown path
(furuta_rt.runtime.hardware) decide with these functions whether a COMMAND takes effect.
"""

from __future__ import annotations

from .messages import wrap_delta


def command_accepted(seq: int, last_sample_sent: int | None, last_accepted: int | None) -> bool:
    """True if a COMMAND answering SAMPLE ``seq`` is accepted (PROTOCOL.md §6).

    Accepted iff ``seq`` is not newer than the last SAMPLE sent and newer than the last accepted
    COMMAND, both modulo 2³². ``last_sample_sent`` None: no SAMPLE sent in this session (nothing can be
    answered); ``last_accepted`` None: no COMMAND accepted yet in this session.
    """
    if last_sample_sent is None or wrap_delta(seq, last_sample_sent) > 0:
        return False
    return last_accepted is None or wrap_delta(seq, last_accepted) > 0


def zero_answer(newest_sample: int | None, last_written: int | None) -> int | None:
    """The seq a host's u = 0 COMMAND must answer to be accepted, or None if none can be.

    The newest SAMPLE received is not newer than the device's last SAMPLE sent, and the device's last
    accepted COMMAND is at most the host's last written one, so a COMMAND answering ``newest_sample``
    is accepted iff ``newest_sample`` is newer than ``last_written``. With None the host has already
    answered every SAMPLE it has: only STOP (§4, no seq) zeroes the actuator before the next tick.
    """
    if newest_sample is None or not command_accepted(newest_sample, newest_sample, last_written):
        return None
    return newest_sample
