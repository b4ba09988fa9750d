"""Child processes that never outlive their parent: a library's pool workers and writer
processes end within about a second of the process that started them, however that one ends
(SIGKILL included), instead of rendering on (and holding GBs) under init.

Two mechanisms, the second a fallback for the first: on Linux the kernel sends the child a
signal when its parent dies (``prctl(PR_SET_PDEATHSIG)``: it fires when the parent *thread*
that started the child ends, so start children from a thread that lives as long as they
should); everywhere, a daemon thread sends that signal when the child's parent pid is no
longer the one it was started by (polled every ``POLL_S`` s; it cannot run while another thread
holds the GIL in one long C call, e.g. one GL draw, so it may wait for that call to return).
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time

PR_SET_PDEATHSIG = 1     # <linux/prctl.h>
POLL_S = 0.5             # seconds between the watchdog's looks at the parent pid
GRACE_S = 5.0            # after the signal, seconds before the watchdog ends the process itself


def die_with_parent(parent: int, sig: int = signal.SIGTERM) -> None:
    """Send this process ``sig`` when ``parent`` (the pid of the process that started it) dies.
    With SIGTERM's default action the process ends at once; a process that handles SIGTERM
    (to remove its temporaries) is ended GRACE_S s later if it has not ended by then."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
        except (OSError, AttributeError):
            pass
    threading.Thread(target=_watch, args=(parent, sig), name="glsim-lifeline", daemon=True).start()


def _watch(parent: int, sig: int) -> None:
    while os.getppid() == parent:        # also true at once if the parent died before prctl
        time.sleep(POLL_S)
    os.kill(os.getpid(), sig)
    time.sleep(GRACE_S)
    os._exit(1)
