"""A run stopped by SIGINT/SIGTERM that makes no progress is ended, so a hung collective cannot
swallow the signal.

The solver stops on a signal at its next poll (every 64 steps): the Python signal handler sets a
flag. A rank blocked in an MPI call that another rank never enters runs no Python code, so its
handler never runs and the signal is lost; only SIGKILL would end the job. A thread of the rank
cannot help: DOLFINx holds the GIL in its collectives (a scatter, ``locate_dofs_topological``),
so no other Python thread runs either. So the watcher is a small separate process per rank. The
C-level signal handler writes the signal number into a pipe (``signal.set_wakeup_fd``) without
the GIL, and each poll of the solver writes a byte into a second pipe. Once a stop signal has
arrived, the watcher waits for polls. If none comes for ``timeout`` seconds, it prints one line
and kills its rank (SIGKILL), which makes ``mpiexec`` end the whole job. The watcher exits by
itself when its rank closes the pipes or dies.

``FENICS_ADAPTIVE_STOP_TIMEOUT`` (seconds, default 30; 0 switches the watchdog off) sets the
timeout. A poll interval (64 steps), the checkpoint and the summary written after the signal
must take less than that.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys

from fenics_adaptive.errors import InputError

DEFAULT_TIMEOUT = 30.0  # s
ENVIRONMENT = "FENICS_ADAPTIVE_STOP_TIMEOUT"

# The watcher process (``python -S -I -c``: no site packages, nothing of the run's state).
# argv: the rank's pid, rank, timeout (s), signal pipe fd, poll pipe fd.
_WATCHER = r"""
import os, select, signal, sys, time
pid, rank, timeout = int(sys.argv[1]), sys.argv[2], float(sys.argv[3])
signals, polls = int(sys.argv[4]), int(sys.argv[5])
for number in (signal.SIGINT, signal.SIGTERM):  # a Ctrl-C or a job's SIGTERM is the rank's
    signal.signal(number, signal.SIG_IGN)
stop = {int(signal.SIGINT): "SIGINT", int(signal.SIGTERM): "SIGTERM"}
signalled, since = None, 0.0
while True:
    ready, _, _ = select.select([signals, polls], [], [], 0.25 if signalled else None)
    for fd in ready:
        data = os.read(fd, 4096)
        if not data:  # the rank closed the pipes, or it is gone
            sys.exit(0)
        if fd == signals and signalled is None:
            names = [stop[b] for b in data if b in stop]
            if names:
                signalled, since = names[0], time.monotonic()
        elif fd == polls and signalled is not None:
            since = time.monotonic()
    if signalled is not None and time.monotonic() - since >= timeout:
        line = f"fenics-adaptive: rank {rank}: no progress for {timeout:g} s after {signalled}"
        os.write(2, (line + "; aborting the MPI job\n").encode())
        os.kill(pid, signal.SIGKILL)
        sys.exit(0)
"""


def timeout_from_environment() -> float:
    """The watchdog's timeout (s) from ``FENICS_ADAPTIVE_STOP_TIMEOUT``; 0 means off. Raises
    InputError for a value that is not a finite number >= 0."""
    text = os.environ.get(ENVIRONMENT, "").strip()
    if not text:
        return DEFAULT_TIMEOUT
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not (0.0 <= value < float("inf")):
        raise InputError(ENVIRONMENT, f"must be a number of seconds >= 0 (got {text!r})")
    return value


class StopWatchdog:
    """Kills this rank when it makes no poll for ``timeout`` s after a stop signal.

    Start it from the main thread (it takes over ``signal.set_wakeup_fd``) once Python handlers
    are installed for SIGINT/SIGTERM (CPython writes to the wakeup pipe only for signals it
    handles). Call ``beat()`` at every poll of the solver and ``close()`` when the run is over.

    Parameters:
        rank: this rank's number (for the message).
        timeout: seconds without a ``beat()`` after a stop signal before the kill (> 0).
    """

    def __init__(self, rank: int, timeout: float):
        self.timeout = float(timeout)
        # the read ends stay open here too: a write never raises SIGPIPE, even if the watcher
        # is gone (a full pipe then just drops the byte)
        self._reads = os.pipe(), os.pipe()
        (signals_read, self._signals), (polls_read, self._polls) = self._reads
        os.set_blocking(self._signals, False)  # the signal handler must never block
        os.set_blocking(self._polls, False)
        arguments = [str(os.getpid()), str(rank), repr(self.timeout)]
        arguments += [str(signals_read), str(polls_read)]
        self._watcher = subprocess.Popen(
            [sys.executable, "-S", "-I", "-c", _WATCHER, *arguments],
            pass_fds=(signals_read, polls_read),
            stdin=subprocess.DEVNULL,
        )
        self._previous_fd = signal.set_wakeup_fd(self._signals, warn_on_full_buffer=False)

    def beat(self) -> None:
        """The solver made progress (a poll)."""
        try:
            os.write(self._polls, b".")
        except BlockingIOError:  # the pipe is full of polls the watcher has not read: alive
            pass

    def close(self) -> None:
        """Stop watching: the watcher sees the pipes close and exits; the previous wakeup fd is
        put back. Main thread only."""
        if self._watcher is None:
            return
        signal.set_wakeup_fd(self._previous_fd)
        os.close(self._signals)
        os.close(self._polls)
        for read, _ in self._reads:
            os.close(read)
        try:
            self._watcher.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            self._watcher.kill()
            self._watcher.wait()
        self._watcher = None
