"""What every eit_skin node does the same way: parameters, diagnostics, main()."""

from __future__ import annotations

import faulthandler
import gc
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager

import rclpy
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.context import Context
from rclpy.exceptions import ParameterUninitializedException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from eit_skin.patch.model import PatchError
from eit_skin.ros.exit_timer import exit_after
from eit_skin.ros.parameters import UNSET_DOUBLES, WRITABLE, ParameterTable
from eit_skin.touch.settings import Setting

READ_ONLY_NOTE = " [read-only: read once at start]"
"""End of a read-only parameter's description (``ros2 param describe``)."""
WRITABLE_NOTE = " [writable while running: takes effect on the next frame]"
"""End of a writable parameter's description."""


def declare_parameters(node: Node, table: ParameterTable, executable: str) -> dict[str, object]:
    """Declare every parameter with a descriptor and return the values.

    The parameters of ``WRITABLE[executable]`` (:data:`~eit_skin.ros.parameters.WRITABLE`)
    may be set while the node runs (:class:`LiveParameters` checks and applies them); the
    others are read-only. ``ros2 param describe`` says which, after the meaning, and shows a
    writable one's bounds as its constraints. A parameter whose default is
    :data:`~eit_skin.ros.parameters.UNSET_DOUBLES` is a double array that stays unset (value
    None) unless given.
    """
    writable = WRITABLE[executable]
    for name, default, description in table:
        live = writable.get(name)
        descriptor = ParameterDescriptor(
            description=description + (WRITABLE_NOTE if live else READ_ONLY_NOTE),
            read_only=live is None,
            additional_constraints=live.bounds_text() if live else "",
        )
        if default is UNSET_DOUBLES:
            default = Parameter.Type.DOUBLE_ARRAY
        node.declare_parameter(name, default, descriptor)
    values: dict[str, object] = {}
    for name, _, _ in table:
        try:
            values[name] = node.get_parameter(name).value
        except ParameterUninitializedException:
            values[name] = None
    return values


class LiveParameters:
    """The writable parameters of a node: a new value is checked, then handed to the node.

    A value outside its bounds (or one ``check`` refuses) is refused as a whole request with
    the reason (``ros2 param set`` prints it); read-only parameters are refused by rclpy.
    Accepted values go to ``apply`` after rclpy stored them, before the next callback of the
    node runs (its next frame).

    Args:
        node: the node, its parameters declared (:func:`declare_parameters`).
        writable: parameter name -> its bounds (``WRITABLE[executable]``).
        apply: called with the changed writable parameters (name -> value).
        check: optional, called with every writable value after the change (name -> value);
            raises ValueError with the reason to refuse it.
    """

    def __init__(
        self,
        node: Node,
        writable: Mapping[str, Setting],
        apply: Callable[[dict[str, object]], None],
        check: Callable[[dict[str, object]], None] | None = None,
    ) -> None:
        self.node = node
        self.writable = writable
        self.apply = apply
        self.check = check
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._changed)

    def values(self) -> dict[str, object]:
        """Every writable parameter's current value."""
        return {name: self.node.get_parameter(name).value for name in self.writable}

    def _validate(self, parameters: list[Parameter]) -> SetParametersResult:
        changed = {p.name: p.value for p in parameters if p.name in self.writable}
        try:
            for name, value in changed.items():
                self.writable[name].check(value)
            if changed and self.check is not None:
                self.check({**self.values(), **changed})
        except ValueError as error:
            return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    def _changed(self, parameters: list[Parameter]) -> None:
        changed = {p.name: p.value for p in parameters if p.name in self.writable}
        if changed:
            self.apply(changed)
            text = ", ".join(f"{name} = {value}" for name, value in changed.items())
            self.node.get_logger().info(f"parameters set: {text}")


def diagnostic_status(
    level: int, name: str, message: str, hardware_id: str, values: dict[str, str]
) -> DiagnosticStatus:
    """A ``diagnostic_msgs/DiagnosticStatus`` (level 0 OK, 1 WARN, 2 ERROR)."""
    return DiagnosticStatus(
        level=bytes([level]),
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=[KeyValue(key=k, value=v) for k, v in values.items()],
    )


#: Environment variable choosing the executor: ``events`` (default) or ``single``.
EXECUTOR_ENV = "EIT_SKIN_EXECUTOR"


#: Shortest time between two log lines about rejected input, s (each one is also counted).
REJECT_LOG_PERIOD_S = 5.0


class ThrottledLog:
    """One log line per ``period_s`` at most, for a message a bad stream repeats every frame.

    rclpy's ``throttle_duration_sec`` looks up its caller's source line on every call, also
    when it prints nothing (about 150 us: more than imaging a frame), so a device sending
    wrong frames at 100 Hz cost a core's percent per patch in logging alone. This checks the
    clock first. A line printed after others were held back says how many.

    Args:
        log: prints one line (e.g. ``node.get_logger().error``).
        period_s: the shortest time between two lines, s (>= 0).
        clock: monotonic seconds (tests pass their own).
    """

    def __init__(
        self,
        log: Callable[[str], object],
        period_s: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not period_s >= 0:
            raise ValueError(f"period_s must be >= 0, got {period_s}")
        self.log = log
        self.period_s = float(period_s)
        self.clock = clock
        self.held = 0  # lines held back since the last one printed
        self._last: float | None = None

    def __call__(self, message: str | Callable[[], str]) -> bool:
        """Print ``message`` (or what it returns, built only when printed); True if printed."""
        now = self.clock()
        if self._last is not None and now - self._last < self.period_s:
            self.held += 1
            return False
        text = message() if callable(message) else message
        if self.held:
            text += f" ({self.held} more since the last such line, {now - self._last:.1f} s ago)"
        self.log(text)
        self._last = now
        self.held = 0
        return True


def make_executor(kind: str | None = None, context: Context | None = None) -> Executor:
    """The executor every eit_skin process spins its nodes with.

    ``events`` (default): rclpy's EventsExecutor, which dispatches ready entities from C++
    instead of rebuilding a wait set over every subscription, timer and service in Python
    on each wake-up; with 20 reconstruction nodes in one process it cut the CPU per image
    by about a third (0.83 -> 0.57 ms, measured on a busy machine). ``single``: the classic
    SingleThreadedExecutor, kept as a fall-back since the EventsExecutor is still marked
    experimental in rclpy.
    """
    kind = kind or os.environ.get(EXECUTOR_ENV, "events")
    if kind == "events":
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:  # rclpy before Kilted: no EventsExecutor
            return SingleThreadedExecutor(context=context)
        return EventsExecutor(context=context)
    if kind == "single":
        return SingleThreadedExecutor(context=context)
    raise ValueError(f"{EXECUTOR_ENV}={kind!r}: expected 'events' or 'single'")


def freeze_start_up_heap() -> None:
    """Collect once, then leave every object that exists now out of later garbage collections.

    What a process builds before it spins (imported modules, meshes, matrices, rclpy
    entities) lives as long as the process, yet Python's full collection walks every tracked
    object: with 50 reconstruction nodes in one process that walk took 30-50 ms, a stall that
    every patch's frames queued behind (bench/standing/skin.md). ``gc.freeze`` moves them to a
    generation the collector never scans; reference counting still frees what is dropped,
    and garbage made while spinning is collected as ever. The price: a start-up object that
    later ends up in an unreachable reference cycle is never freed (bench/stress/soak.md: no
    growth).
    """
    gc.collect()
    gc.freeze()


def spin_nodes(
    nodes: Sequence[Node], kind: str | None = None, stop: threading.Event | None = None
) -> None:
    """Spin ``nodes`` in one executor (:func:`make_executor`) until shutdown or ``stop``.

    A loop of 0.2 s ``spin_until_future_complete`` calls on a future that never completes,
    because the EventsExecutor's ``spin()`` of the Kilted wheels neither ran our timers nor
    returned on shutdown. Each call dispatches every event of its 0.2 s without coming back
    to Python (``spin_once`` returned after each one: a Python loop pass per frame); the
    loop returns within 0.2 s of a shutdown (another thread, whatever moment it lands) or of
    ``stop`` being set (a signal).
    """
    context = nodes[0].context
    executor = make_executor(kind, context)
    for node in nodes:
        executor.add_node(node)
    never = Future()
    try:
        while context.ok() and not (stop is not None and stop.is_set()):
            executor.spin_until_future_complete(never, timeout_sec=0.2)
    except ExternalShutdownException:
        pass  # the context was shut down while waiting: the normal way out
    except Exception:
        # shut down after the loop's check but before the executor built its wait set:
        # rclpy raises RCLError ("the given context is not valid"), the same way out
        if context.ok():
            raise
    finally:
        executor.shutdown(timeout_sec=1.0)


class StopSignals:
    """SIGINT and SIGTERM as a request to stop, never an exception inside a callback.

    rclpy's own handler shuts the context down at once and lets Python raise
    KeyboardInterrupt wherever the main thread happens to be: inside a callback (a
    traceback) or while a reader thread still publishes (an error after shutdown). Here a
    signal only sets :attr:`requested`; the spin loop sees it between callbacks, and the
    node is destroyed (threads joined, files closed) before the context shuts down.
    Before :attr:`spinning` is set (a node still building its matrices) a signal raises
    KeyboardInterrupt, so a slow start can still be interrupted.

    Python runs a handler only when the main thread comes back to Python. A main thread
    stuck in native code (a DDS wait that cannot retake a mutex a deadlocked DDS thread
    holds) never does; so the C-level handler's byte (``signal.set_wakeup_fd``) also wakes a
    watcher thread, which while spinning arms the watchdog of :meth:`report_hung_cleanup`:
    every thread's stack and exit 1 after :attr:`stuck_timeout_s`, unless the main thread
    gets to its clean-up first (which re-arms it).
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.requested = threading.Event()
        self.spinning = False
        self.first_signal_s: float | None = None  # time.monotonic() of the first signal
        self.stuck_timeout_s = SHUTDOWN_TIMEOUT_S  # s, signal to exit when nothing else runs

    def _handle(self, signum: int, frame: object) -> None:
        if self.first_signal_s is None:
            self.first_signal_s = time.monotonic()
        self.requested.set()
        if not self.spinning:
            raise KeyboardInterrupt

    @contextmanager
    def installed(self) -> Iterator[StopSignals]:
        """Handle the signals while inside the block; the previous handlers after it."""
        previous = {sig: signal.signal(sig, self._handle) for sig in self.SIGNALS}
        wakeup, write = os.pipe()
        os.set_blocking(write, False)
        previous_write = signal.set_wakeup_fd(write, warn_on_full_buffer=False)
        threading.Thread(target=self._watch, args=(wakeup,), daemon=True).start()
        try:
            yield self
        finally:
            signal.set_wakeup_fd(previous_write)
            os.close(write)  # the watcher reads the end of the pipe and returns
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def _watch(self, wakeup: int) -> None:
        """While spinning, each signal's byte requests a stop and arms its watchdog."""
        with os.fdopen(wakeup, "rb", buffering=0) as pipe:
            while pipe.read(64):
                if self.spinning:
                    self.requested.set()
                    faulthandler.dump_traceback_later(self.stuck_timeout_s, exit=True)

    def ignore(self) -> None:
        """Ignore further signals (while cleaning up after the first one)."""
        for sig in self.SIGNALS:
            signal.signal(sig, signal.SIG_IGN)

    def report_hung_cleanup(self, timeout_s: float) -> None:
        """A node's clean-up after the first signal: reported if it hangs, never silent.

        A second Ctrl-C is ignored. SIGTERM (``ros2 launch`` sends it 5 s after its SIGINT,
        a service manager after its grace time) prints every thread's stack to the log and
        ends the process; so does a watchdog after ``timeout_s``, with exit 1. A clean-up
        stuck inside native code no longer waits for SIGKILL.
        """
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        faulthandler.register(signal.SIGTERM, all_threads=True, chain=True)
        faulthandler.dump_traceback_later(timeout_s, exit=True)


SHUTDOWN_TIMEOUT_S = 15.0
"""Ceiling (s) of a node's own clean-up after its stop signal (threads joined, files closed)."""
STOP_DEADLINE_S = 4.5
"""Time (s) from the stop signal by which the process has ended, unless its own clean-up
still runs: below the 5 s ``ros2 launch`` waits before it sends SIGTERM."""
MIN_TEARDOWN_S = 0.5
"""Time (s) rclpy's teardown gets at least, after a clean-up that used up the deadline."""


def _bound_dds_teardown(timeout_s: float, executable: str) -> None:
    """Whatever happens in rclpy/Fast DDS from now on, the process ends within ``timeout_s``.

    Called once the node's own clean-up is done, so nothing is lost by ending here. A
    teardown that has not finished by then (a loaded machine, or the Fast DDS deadlock of
    docs/nodes.md "Stopping") is cut by a native timer (:func:`exit_after`) with exit 0 and
    one line on stderr; the timer runs even when a thread is stuck in native code holding the
    GIL. Without POSIX timers the 15 s watchdog stays in charge.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    exit_after(
        timeout_s,
        0,
        f"{executable}: rclpy/DDS teardown not done {STOP_DEADLINE_S:.1f} s after the stop signal; "
        "files are closed, exiting 0 (docs/nodes.md, Stopping)",
    )


def run_node(make_node: Callable[[], Node], executable: str, args: list[str] | None) -> int:
    """Spin a node until SIGINT/SIGTERM (exit 0); a bad configuration exits 2 with one line.

    On a signal the node's own resources go first (``close_resources()`` if it has one:
    threads stopped, recordings closed), then rclpy destroys the node and shuts the context
    down: no traceback, no publishing after shutdown. Neither step can hang silently: the
    first is bounded by :data:`SHUTDOWN_TIMEOUT_S` (stacks in the log, exit 1, or SIGTERM
    ends it: :meth:`StopSignals.report_hung_cleanup`), the second by
    :data:`STOP_DEADLINE_S` after the signal (one line on stderr, exit 0:
    :func:`_bound_dds_teardown`).
    """
    signals = StopSignals()
    node = None
    with signals.installed():
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
            try:
                node = make_node()
            except (PatchError, FileNotFoundError, KeyError, ValueError) as error:
                print(f"{executable}: refusing to start: {error}", file=sys.stderr)
                return 2
            signals.spinning = True
            freeze_start_up_heap()
            spin_nodes([node], stop=signals.requested)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            signals.report_hung_cleanup(SHUTDOWN_TIMEOUT_S)
            if node is not None:
                close_resources = getattr(node, "close_resources", None)
                if close_resources is not None:
                    close_resources()  # threads joined, recordings closed
                since = signals.first_signal_s or time.monotonic()  # or a context shutdown
                left = STOP_DEADLINE_S - (time.monotonic() - since)
                _bound_dds_teardown(max(MIN_TEARDOWN_S, left), executable)
                node.destroy_node()
            if rclpy.ok():
                rclpy.shutdown()
    return 0
