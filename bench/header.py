"""The first line of every benchmark report: the command, the machine, its load and the date.

One writer for all of bench/, so that every report says the same things the same way and a
reader can tell an idle run from a loaded one.
"""

from __future__ import annotations

import math
import os
import platform
import shlex
import sys
import time

import numpy as np

#: Environment variables that change a benchmark's numbers; named in the command when set.
TUNING_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")


def command() -> str:
    """The running benchmark's command as typed from the repository root, e.g.
    ``OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.standing.bench_skin --patches 10``."""
    env = "".join(f"{k}={os.environ[k]} " for k in TUNING_VARIABLES if k in os.environ)
    spec = getattr(sys.modules["__main__"], "__spec__", None)
    script = f"-m {spec.name}" if spec is not None else shlex.quote(sys.argv[0])
    return f"{env}.venv/bin/python {script}{''.join(' ' + shlex.quote(a) for a in sys.argv[1:])}"


def machine() -> str:
    """Host name, cores, architecture, Python and numpy, e.g. ``vm: 2 cores, x86_64, ...``."""
    return (
        f"{platform.node()}: {os.cpu_count()} cores, {platform.machine()}, "
        f"Python {platform.python_version()}, numpy {np.__version__}"
    )


def load_average() -> float:
    """The machine's 1-minute load average (NaN where the system has none)."""
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan


def run_header(load_before: float | None = None) -> str:
    """``command`` on ``machine``; the UTC date; the 1-min load average before (if given)
    and now, and whether other work shared the machine (load above half the cores)."""
    now = load_average()
    loads = [f"{load_before:.1f} before the run"] if load_before is not None else []
    loads.append(f"{now:.1f} at the end (this run included)")
    busy = max(now, load_before or 0.0) > 0.5 * (os.cpu_count() or 1)
    state = "shared with other work: times are upper bounds" if busy else "otherwise idle"
    return (
        f"`{command()}` on {machine()}; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; "
        f"1-min load average {', '.join(loads)}; {state}."
    )
