"""Console scripts of the nodes: a Ctrl-C that comes while the node still imports is quiet.

A node process spends its first second or more importing rclpy, numpy, scipy and the core.
``ros2 launch`` forwards Ctrl-C at once, so a launch stopped early sent SIGINT into those
imports and every node printed a KeyboardInterrupt traceback. Here SIGINT and SIGTERM are
handled before anything heavy is imported: one that arrives during the imports ends the
process with exit 0 and no output (nothing has started, nothing needs cleaning up);
afterwards :func:`eit_skin.ros.node_runner.run_node` installs its own handling.

For bug reports from a robot: a crash (SIGSEGV, SIGABRT, ...) prints every thread's Python
stack to the node's log, and ``kill -USR1 <pid>`` prints them without stopping the node
(Python's :mod:`faulthandler`).
"""

from __future__ import annotations

import faulthandler
import importlib
import signal


def _stop_while_importing(signum: int, frame: object) -> None:
    raise SystemExit(0)


def _run(module: str) -> int:
    """``eit_skin.ros.<module>.main()`` with quiet signals until its own handling starts."""
    faulthandler.enable(all_threads=True)
    faulthandler.register(signal.SIGUSR1, all_threads=True, chain=False)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _stop_while_importing)
    try:
        return importlib.import_module(f"eit_skin.ros.{module}").main()
    finally:
        # the node has stopped (its own handling restored ours on the way out): a late
        # signal, a launch's second SIGINT or a dying starter's SIGTERM, must not raise
        # SystemExit inside the interpreter's exit handlers (a traceback in the log); the
        # exit itself is bounded by the node runner's exit timer
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)


def driver() -> int:
    """Console script ``eit_driver``."""
    return _run("driver")


def reconstruction() -> int:
    """Console script ``eit_reconstruction``."""
    return _run("reconstruction")


def classifier() -> int:
    """Console script ``eit_classifier``."""
    return _run("classifier")
