"""The executor every eit_skin process spins with: real nodes, real DDS, both kinds."""

from __future__ import annotations

import subprocess
import sys
import threading

import pytest
import rclpy
from rclpy.context import Context
from std_msgs.msg import UInt32

from eit_skin.ros.node_runner import EXECUTOR_ENV, ThrottledLog, make_executor, spin_nodes

pytestmark = pytest.mark.ros


def test_unknown_executor_names_the_variable(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(EXECUTOR_ENV, "fastest")
    with pytest.raises(ValueError, match=f"{EXECUTOR_ENV}='fastest'"):
        make_executor()


@pytest.mark.parametrize("kind", ["events", "single"])
def test_spin_nodes_delivers_messages_runs_timers_and_returns_on_shutdown(kind: str) -> None:
    """Two nodes in one executor: 50 messages arrive in order, the timer ticks, and a
    shutdown from another thread ends spin_nodes."""
    context = Context()
    rclpy.init(context=context)
    try:
        sender = rclpy.create_node("sender", context=context)
        receiver = rclpy.create_node("receiver", context=context)
        got: list[int] = []
        ticks: list[int] = []
        done = threading.Event()

        def on_message(msg: UInt32) -> None:
            got.append(msg.data)
            if len(got) == 50:
                done.set()

        receiver.create_subscription(UInt32, "count", on_message, 100)
        pub = sender.create_publisher(UInt32, "count", 100)
        sent = [0]

        def send() -> None:  # reliable QoS: publish once the subscription is matched
            ticks.append(1)
            if pub.get_subscription_count() and sent[0] < 50:
                for _ in range(10):
                    pub.publish(UInt32(data=sent[0]))
                    sent[0] += 1

        sender.create_timer(0.02, send)
        threading.Timer(20.0, done.set).start()  # a hang fails below instead of blocking
        stopper = threading.Thread(target=lambda: (done.wait(), context.try_shutdown()))
        stopper.start()
        spin_nodes([sender, receiver], kind)
        stopper.join(5.0)
        assert got == list(range(50))
        assert len(ticks) >= 5
        assert not context.ok()
    finally:
        context.try_shutdown()


@pytest.mark.parametrize("kind", ["events", "single"])
def test_a_shutdown_just_before_the_executor_waits_ends_spin_nodes_quietly(
    kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The race another thread's shutdown can win: spin_nodes has seen the context ok, and
    the context shuts down before the executor builds its wait set (rclpy then raises
    RCLError "the given context is not valid"; seen once in a 3-copy run). Here the
    shutdown is put exactly there: spin_nodes returns as for any shutdown."""
    context = Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node("raced", context=context)
        executor = make_executor(kind, context)
        original = type(executor).spin_until_future_complete

        def shut_down_first(self, future, timeout_sec=None):
            context.try_shutdown()
            return original(self, future, timeout_sec)

        monkeypatch.setattr(type(executor), "spin_until_future_complete", shut_down_first)
        spin_nodes([node], kind)
        assert not context.ok()
    finally:
        context.try_shutdown()


def _python_child(script: str, argument: str) -> subprocess.Popen:
    """``python -c script argument`` with its stdout and stderr piped (text)."""
    return subprocess.Popen(
        [sys.executable, "-c", script, argument],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


FROZEN_BEFORE_SPIN = """
import gc, sys, weakref
import rclpy
from rclpy.node import Node
from eit_skin.ros.node_runner import run_node

class Cycle:
    pass

def make_node():
    node = Node("frozen_heap_probe")
    node.built = Cycle()
    node.built.me = node.built  # a cycle alive when the node starts spinning
    def tick():
        built = weakref.ref(node.built)
        del node.built  # garbage now, but made before the spin: frozen, never scanned
        later = Cycle()
        later.me = later  # garbage made while spinning: collected as ever
        later = weakref.ref(later)
        gc.collect()
        print(gc.get_freeze_count() > 0, built() is not None, later() is None, flush=True)
        rclpy.shutdown()
    node.create_timer(0.01, tick)
    return node

sys.exit(run_node(make_node, "frozen_heap_probe", []))
"""


def test_a_node_process_leaves_its_start_up_objects_out_of_garbage_collections() -> None:
    """run_node freezes what exists when the node starts spinning (a full collection over a
    process's start-up objects stalled 50 patches' frames 30-50 ms): a cycle built before
    is never scanned again, while garbage made while spinning is still collected."""
    process = _python_child(FROZEN_BEFORE_SPIN, "")
    try:
        stdout, stderr = process.communicate(timeout=120)
    finally:
        process.kill()
    assert process.returncode == 0, stderr
    assert stdout.splitlines() == ["True True True"], stderr


HUNG_CLEANUP = """
import sys, threading
from eit_skin.ros.node_runner import StopSignals
StopSignals().report_hung_cleanup(float(sys.argv[1]))
print("cleaning up", flush=True)
threading.Event().wait()  # a clean-up that never ends
"""


@pytest.mark.parametrize("how", ["watchdog", "sigterm"])
def test_a_hung_cleanup_is_reported_with_its_stack_and_ends(how: str) -> None:
    """A node stuck in its clean-up after the first signal: a second SIGINT is ignored,
    SIGTERM (or the watchdog) ends it with every thread's stack printed, never a hang."""
    import signal

    timeout_s = "2.0" if how == "watchdog" else "600"
    process = _python_child(HUNG_CLEANUP, timeout_s)
    try:
        assert process.stdout.readline() == "cleaning up\n"
        process.send_signal(signal.SIGINT)  # ignored: the clean-up goes on
        if how == "sigterm":
            process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=120)
    finally:
        process.kill()
    assert process.returncode == (1 if how == "watchdog" else -signal.SIGTERM), stderr
    assert "in <module>" in stderr and "hread 0x" in stderr, stderr  # "Current thread 0x..."
    assert "KeyboardInterrupt" not in stderr, stderr


SIGNAL_WHILE_STUCK = """
import ctypes
from eit_skin.ros.node_runner import StopSignals
libc = ctypes.CDLL(None)
mutex = ctypes.create_string_buffer(64)  # a default pthread mutex (all zeros)
signals = StopSignals()
signals.stuck_timeout_s = 1.0
with signals.installed():
    signals.spinning = True
    libc.pthread_mutex_lock(mutex)
    print("stuck", flush=True)
    libc.pthread_mutex_lock(mutex)  # locked again: blocks in C for ever, the GIL released
"""


def test_a_signal_ends_a_node_whose_main_thread_is_stuck_in_native_code() -> None:
    """The main thread blocked in C (as in a DDS wait that cannot retake a mutex a
    deadlocked DDS thread holds) never runs a Python signal handler: the C handler's
    wakeup byte still arms the watchdog, which prints every thread's stack and ends the
    process (exit 1) instead of leaving it to SIGKILL."""
    import signal

    process = _python_child(SIGNAL_WHILE_STUCK, "")
    try:
        assert process.stdout.readline() == "stuck\n"
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == 1, stderr
    assert "in <module>" in stderr and "hread 0x" in stderr, stderr


STUCK_AT_EXIT = """
import ctypes
from eit_skin.ros.exit_timer import exit_after
libc = ctypes.CDLL(None)
# a C exit handler that blocks, as a C++ static destructor joining a DDS thread can: it runs
# after the interpreter has finalised and freed every Python object
assert libc.__cxa_atexit(ctypes.cast(libc.pause, ctypes.c_void_p), None, None) == 0
assert exit_after(1.0, 3, "the message of a teardown stuck at exit")
print("exiting", flush=True)
"""


def test_the_timer_message_survives_the_interpreter_finalising() -> None:
    """A process stuck after Python has finalised (every Python object freed) still writes the
    armed message intact, then ends with the armed status: the text lives in C memory (a
    Python buffer printed allocator garbage there)."""
    process = _python_child(STUCK_AT_EXIT, "")
    try:
        stdout, stderr = process.communicate(timeout=120)
    finally:
        process.kill()
    assert stdout == "exiting\n", stderr
    assert process.returncode == 3, stderr
    assert stderr.endswith(": the message of a teardown stuck at exit\n"), stderr


STUCK_IN_NATIVE_CODE = """
import ctypes, sys
from eit_skin.ros.exit_timer import exit_after
from eit_skin.ros.node_runner import _bound_dds_teardown
if sys.argv[1] == "teardown":
    _bound_dds_teardown(1.0, "stuck_node")
else:
    assert exit_after(1.0, int(sys.argv[1]))
print("stuck", flush=True)
ctypes.PyDLL(None).sleep(600)  # native code keeping the GIL, as in the Fast DDS deadlock
"""


@pytest.mark.parametrize("how", ["teardown", "3"])
def test_a_process_stuck_in_native_code_holding_the_gil_still_ends(how: str) -> None:
    """The stop's DDS phase stuck: no Python can run once a thread sleeps in native code with
    the GIL held, yet the native timer ends the process with the armed status (3 shows it is
    the timer's, not a normal exit), saying why when it cuts a node's teardown."""
    process = _python_child(STUCK_IN_NATIVE_CODE, how)
    try:
        stdout, stderr = process.communicate(timeout=120)  # a ceiling: sleep(600) otherwise
    finally:
        process.kill()
    assert stdout == "stuck\n", stderr
    assert process.returncode == (0 if how == "teardown" else 3), stderr
    if how == "teardown":  # one line says why, then exit 0
        assert "stuck_node: rclpy/DDS teardown not done" in stderr, stderr


SIGNAL_DURING_EXIT = """
import atexit, os, signal, sys, time, types
from eit_skin.ros import entry
def main():  # a node that stopped cleanly; its process then gets a late SIGTERM while exiting
    atexit.register(lambda: (os.kill(os.getpid(), signal.SIGTERM), time.sleep(0.2)))
    return 0
sys.modules["eit_skin.ros.classifier"] = types.SimpleNamespace(main=main)
sys.exit(entry.classifier())
"""


def test_a_signal_during_the_interpreter_exit_is_quiet() -> None:
    """A launch's second SIGINT or a dying starter's SIGTERM that lands while a stopped node's
    interpreter exits: exit 0 and nothing on stderr (it raised SystemExit inside an atexit
    handler and printed a traceback)."""
    process = _python_child(SIGNAL_DURING_EXIT, "")
    try:
        _, stderr = process.communicate(timeout=120)
    finally:
        process.kill()
    assert (process.returncode, stderr) == (0, ""), stderr


def test_throttled_log_prints_once_per_period_and_counts_what_it_held_back() -> None:
    lines: list[str] = []
    now = [100.0]
    log = ThrottledLog(lines.append, 5.0, clock=lambda: now[0])
    built: list[int] = []

    def message() -> str:
        built.append(1)
        return "late"

    assert log("bad frame") is True
    for _ in range(99):  # a bad stream at 100 Hz for a second: held, nothing built
        now[0] += 0.01
        assert log(message) is False
    assert lines == ["bad frame"] and not built and log.held == 99
    now[0] = 105.0  # the period is over
    assert log(message) is True
    assert lines[1] == "late (99 more since the last such line, 5.0 s ago)"
    assert log.held == 0 and len(built) == 1
    now[0] = 120.0  # nothing held back: no count
    log("again")
    assert lines[2] == "again"
    with pytest.raises(ValueError, match="period_s"):
        ThrottledLog(lines.append, -1.0)
