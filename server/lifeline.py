"""Children of ``jointseg serve`` that die with it, even when it is killed with SIGKILL.

Why: a SIGKILL gives ``serve`` no chance to stop its children. Orphans (re-parented to init)
kept the viewer's port and went on serving results, and the restarted service's viewer had to
move to another port. Every process ``serve`` starts calls :func:`die_with_parent` first:

- on Linux, ``prctl(PR_SET_PDEATHSIG, sig)`` makes the kernel send ``sig`` the moment the
  parent goes, even to a child busy in native code. The kernel sends it when the *thread* that
  started the child exits, so it is asked for (``kernel=True``) only by children started from
  threads that live as long as ``serve``: its main thread (workers, viewer) and its supervisor
  thread (restarted workers). The checking processes of :mod:`server.api.checks` are started
  from request threads that come and go, so they rely on the watchdog alone;
- everywhere, a daemon thread polls ``os.getppid()``: once the parent is gone it sends ``sig``
  itself (where the kernel was not asked), and kills the process with SIGKILL if it is still
  alive ``grace_s`` later (a worker gets time to put its job back in the queue; see
  :func:`server.worker.process.worker_main`).

The multiprocessing resource tracker runs no code of ours: it exits by itself once every
process holding its pipe (``serve`` and these children) has exited.
"""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import sys
import threading
import time

log = logging.getLogger(__name__)

#: ``PR_SET_PDEATHSIG`` of <linux/prctl.h>.
_PR_SET_PDEATHSIG = 1
#: Seconds between two looks at the parent.
POLL_S = 0.25
#: Seconds a child gets after SIGTERM (from ``serve``'s stop, or its death) before SIGKILL.
STOP_GRACE_S = 20.0


def _ask_kernel(sig: int) -> bool:
    """``prctl(PR_SET_PDEATHSIG, sig)``; False where it is not available."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()))
    except (OSError, AttributeError) as exc:
        log.warning("prctl(PR_SET_PDEATHSIG) failed (%s); watching the parent instead", exc)
        return False
    return True


def die_with_parent(
    parent_pid: int,
    *,
    sig: int = signal.SIGTERM,
    grace_s: float = 5.0,
    kernel: bool = True,
) -> None:
    """Stop this process with ``sig`` when ``parent_pid`` exits, and kill it ``grace_s`` later.

    Parameters
    ----------
    parent_pid : int
        The process that started this one (``serve``).
    sig : int
        What this process gets when its parent is gone (SIGTERM: it stops cleanly; SIGKILL).
    grace_s : float
        Seconds it may take to exit on ``sig`` before it is killed with SIGKILL.
    kernel : bool
        Ask the kernel too (Linux); only for children of a thread that lives as long as the
        parent process (see the module doc).
    """
    armed = kernel and _ask_kernel(sig)
    if os.getppid() != parent_pid:  # gone before the kernel was asked
        log.warning("parent %d is already gone; stopping", parent_pid)
        os.kill(os.getpid(), sig)
    watch = threading.Thread(
        target=_watch,
        args=(parent_pid, sig, grace_s, armed),
        name="jointseg-lifeline",
        daemon=True,
    )
    watch.start()


def _watch(parent_pid: int, sig: int, grace_s: float, armed: bool) -> None:
    while os.getppid() == parent_pid:
        time.sleep(POLL_S)
    log.warning("parent %d is gone; stopping (pid %d)", parent_pid, os.getpid())
    if not armed:
        os.kill(os.getpid(), sig)
    time.sleep(grace_s)
    log.error("still running %.0f s after the parent died; killing pid %d", grace_s, os.getpid())
    os.kill(os.getpid(), signal.SIGKILL)
