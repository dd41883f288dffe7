"""A process exit that needs neither the GIL nor any Python thread to run.

At shutdown a node's last step, rclpy destroying its DDS entities, can deadlock inside Fast
DDS (eProsima/Fast-DDS#6502: a receive thread holding the PDP mutex waits for the event thread,
which waits for that mutex; seen about once in a few hundred stops when many nodes stop at
once). The thread calling rclpy then blocks in native code while holding the GIL, so no Python
code, not even a watchdog thread or a signal handler, can run again. :func:`exit_after` arms a
POSIX timer whose ``SIGEV_THREAD`` notification is libc's ``_exit`` itself: the thread that
glibc starts when the timer fires calls ``_exit(code)`` directly.
"""

from __future__ import annotations

import ctypes
import sys

_SIGEV_THREAD = 2
_CLOCK_MONOTONIC = 1


class _Sigval(ctypes.Union):
    _fields_ = [("sival_int", ctypes.c_int), ("sival_ptr", ctypes.c_void_p)]


class _Sigevent(ctypes.Structure):
    """``struct sigevent`` with its SIGEV_THREAD members (64 bytes with the padding)."""

    _fields_ = [
        ("sigev_value", _Sigval),
        ("sigev_signo", ctypes.c_int),
        ("sigev_notify", ctypes.c_int),
        ("sigev_notify_function", ctypes.c_void_p),
        ("sigev_notify_attributes", ctypes.c_void_p),
        ("_pad", ctypes.c_byte * 32),
    ]


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


class _Itimerspec(ctypes.Structure):
    _fields_ = [("it_interval", _Timespec), ("it_value", _Timespec)]


def _posix_timers() -> tuple[ctypes.CDLL, object, object] | None:
    if not sys.platform.startswith("linux"):
        return None
    libc = ctypes.CDLL(None, use_errno=True)
    try:
        return libc, libc.timer_create, libc.timer_settime
    except AttributeError:  # glibc before 2.34 keeps them in librt
        librt = ctypes.CDLL("librt.so.1", use_errno=True)
        return libc, librt.timer_create, librt.timer_settime


def _call_after(timers: tuple, seconds: float, function: object, argument: int) -> bool:
    """Arm a one-shot timer calling the C ``function(argument)`` from a new native thread."""
    _, timer_create, timer_settime = timers
    event = _Sigevent()
    event.sigev_value.sival_ptr = argument  # all 8 bytes defined; an int reads the low half
    event.sigev_notify = _SIGEV_THREAD
    event.sigev_notify_function = ctypes.cast(function, ctypes.c_void_p).value
    timer = ctypes.c_void_p()
    if timer_create(_CLOCK_MONOTONIC, ctypes.byref(event), ctypes.byref(timer)) != 0:
        return False
    whole = int(seconds)
    when = _Itimerspec(it_value=_Timespec(whole, int((seconds - whole) * 1e9)))
    return timer_settime(timer, 0, ctypes.byref(when), None) == 0


def exit_after(seconds: float, code: int = 0, message: str = "") -> bool:
    """End the process with exit status ``code`` after ``seconds`` (s), whatever it is doing.

    The notification function receives the timer's ``union sigval`` by value, which the C
    calling conventions of Linux on x86-64 and arm64 pass in the first integer register:
    ``_exit`` reads it as its ``int`` status. A ``message`` goes to stderr (libc ``warnx``:
    "<program>: <message>", unbuffered) 50 ms before. Nothing else is flushed then (flush
    Python's streams before arming). Returns False, arming nothing, where POSIX timers are
    missing (not Linux).
    """
    timers = _posix_timers()
    if timers is None:
        return False
    libc = timers[0]
    if message:
        _call_after(timers, max(0.0, seconds - 0.05), libc.warnx, _c_string(libc, message))
    return _call_after(timers, seconds, libc._exit, code)


def _c_string(libc: ctypes.CDLL, text: str) -> int:
    """Address of a NUL-terminated copy of ``text`` in C memory that is never freed.

    Not a Python-owned buffer: the timer may fire while the interpreter finalises, after it
    has cleared the modules and freed their objects (a teardown stuck at exit); a freed
    buffer then printed allocator garbage. One small leak per armed message.
    """
    data = text.replace("%", "percent").encode() + b"\0"
    malloc = libc.malloc
    malloc.restype, malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
    address = malloc(len(data))
    if not address:
        raise MemoryError("exit_after: no memory for the message")
    ctypes.memmove(address, data, len(data))
    return address
