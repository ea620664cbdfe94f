"""A Meshcat server subprocess that ends with the process that started it.

meshcat's own `start_zmq_server_as_subprocess` stops its server from an `atexit` hook,
which never runs when the parent is killed (SIGKILL, OOM): the server was left running.
Here the server is started through a small launcher that ends it when its parent goes:
on Linux the kernel sends it SIGKILL (PR_SET_PDEATHSIG), and everywhere a watchdog
thread exits it once its parent process id changes (the parent died, it was re-parented).
"""

from __future__ import annotations

import atexit
import os
import subprocess
import sys
import threading

import meshcat
from meshcat.servers.zmqserver import match_web_url, match_zmq_url

# Runs in the child: argv[1] is the parent's pid, argv[2] "1" when PR_SET_PDEATHSIG may be
# used (the kernel ties it to the thread that forked, so only when that is the main thread).
_LAUNCHER = """\
import os, runpy, signal, sys, threading, time
parent = int(sys.argv[1])
if sys.argv[2] == "1" and sys.platform.startswith("linux"):
    import ctypes
    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
def watch():
    while os.getppid() == parent:
        time.sleep(0.2)
    os._exit(0)
if os.getppid() != parent:
    os._exit(0)
threading.Thread(target=watch, daemon=True).start()
sys.argv = ["meshcat-server", *sys.argv[3:]]
runpy.run_module("meshcat.servers.zmqserver", run_name="__main__", alter_sys=True)
"""


def start_server() -> subprocess.Popen:
    """Start a Meshcat server tied to this process; returns the process, its URLs read.

    The process carries `zmq_url` and `web_url` attributes. It is also killed at exit (as
    meshcat does), so an orderly exit stops it at once.
    """
    main = threading.current_thread() is threading.main_thread()
    env = dict(os.environ)  # as meshcat: its own folder on the path, the rest kept
    env["PYTHONPATH"] = os.path.dirname(os.path.dirname(os.path.abspath(meshcat.__file__)))
    argv = [sys.executable, "-u", "-c", _LAUNCHER, str(os.getpid()), "1" if main else "0"]
    # a new session, as meshcat: a Ctrl-C at the terminal reaches the parent only
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                            start_new_session=True)
    atexit.register(_stop, proc)
    line = ""
    while "zmq_url" not in line:
        raw = proc.stdout.readline()
        line = raw.strip().decode("utf-8", "replace")
        if not raw:  # its output closed: it is exiting
            proc.wait()
            err = proc.stderr.read().decode("utf-8", "replace").strip().splitlines()
            raise RuntimeError(f"the meshcat server exited at start (exit code {proc.returncode}"
                               + (f": {err[-1]}" if err else "") + ")")
    proc.zmq_url = match_zmq_url(line)
    proc.web_url = match_web_url(proc.stdout.readline().strip().decode("utf-8", "replace"))
    return proc


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait()


class _Window(meshcat.visualizer.ViewerWindow):
    """meshcat's window on a server this module started (its `__init__` would start its own)."""

    def __init__(self, proc: subprocess.Popen):  # noqa: super().__init__ not called on purpose
        self.server_proc, self.zmq_url, self.web_url = proc, proc.zmq_url, proc.web_url
        self.connect_zmq()


def visualizer() -> meshcat.Visualizer:
    """A `meshcat.Visualizer` on a fresh server started by `start_server`.

    Its `window.server_proc` is the server process, as with meshcat's own start.
    """
    proc = start_server()
    try:
        return meshcat.Visualizer(window=_Window(proc))
    except BaseException:
        _stop(proc)
        raise
