"""Shared fixtures: one EGL context for every GL test, its error flag checked around each; a
virtual X server (Xvfb) for the window tests and ``preview_window`` to run one there."""
import contextlib
import fcntl
import os
import shutil
import subprocess
import sys

import pytest

from glsim.backends.gl.context import create_context
from glsim.errors import GLUnavailableError


@pytest.fixture(scope="session")
def gl_ctx():
    """The shared EGL context; where none can be made, every test that needs it is skipped with
    the reason (the CPU oracle's tests still run)."""
    try:
        ctx = create_context()
    except GLUnavailableError as exc:
        pytest.skip(f"no OpenGL context: {exc}")
    yield ctx
    ctx.release()


@pytest.fixture
def ctx_for(request):
    """``ctx_for(backend)``: the shared EGL context for "gl" (made on first use), None for "cpu"."""
    def make(backend):
        return request.getfixturevalue("gl_ctx") if backend == "gl" else None
    return make


@pytest.fixture(autouse=True)
def _gl_error_check(request):
    """GL tests start with the shared context current (a test before may have opened and closed
    another) and start and end with GL_NO_ERROR (moderngl's own tests do the same)."""
    if request.node.get_closest_marker("gl") is None:
        yield
        return
    ctx = request.getfixturevalue("gl_ctx")
    ctx.__enter__()
    assert ctx.error == "GL_NO_ERROR"
    yield
    assert ctx.error == "GL_NO_ERROR"


@pytest.fixture(scope="session")
def shared_dir(tmp_path_factory):
    """``shared_dir(name, make)``: a directory that ``make(path)`` fills once per test run, shared
    by the run's xdist workers (a module-scoped fixture is otherwise built by each worker that gets
    one of its tests): the first to ask builds it under a file lock, the others wait and read it.
    ``make`` must depend on nothing but ``name``; callers copy it before changing anything in it.
    ``wait=False``: None at once where another worker is building it (to build another meanwhile)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):   # each worker's basetemp lies in the run's own directory
        root = root.parent

    def get(name, make, wait=True):
        d = root / f"shared-{name}"
        with open(root / f"shared-{name}.lock", "w") as lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
            except BlockingIOError:
                return None
            if not (root / f"shared-{name}.done").exists():
                shutil.rmtree(d, ignore_errors=True)   # a build that failed part way
                make(d)
                (root / f"shared-{name}.done").touch()
        return d
    return get


@pytest.fixture(scope="session")
def xserver():
    """A display number of a private Xvfb, started once and stopped at the end."""
    tools = [t for t in ("Xvfb", "xdotool", "xwd") if shutil.which(t) is None]
    if tools:
        pytest.skip(f"{', '.join(tools)} not installed (make test installs xvfb, xdotool and x11-apps as root)")
    read, write = os.pipe()       # Xvfb picks a free display number and writes it here
    proc = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, pass_fds=(write,))
    os.close(write)
    with os.fdopen(read) as f:
        number = f.readline().strip()
    if not number:
        proc.kill()
        pytest.skip("Xvfb did not start")
    display = f":{number}"
    yield display
    proc.terminate()
    proc.wait(10)


@pytest.fixture
def preview_window(xserver):
    """``with preview_window(*cli_args, cwd=...) as (app, env):`` runs ``glsim preview …`` on the
    Xvfb display (stdout and stderr piped as text; ``env`` has its DISPLAY, for xdotool) and
    kills it on the way out if it is still running."""
    env = {**os.environ, "DISPLAY": xserver}

    @contextlib.contextmanager
    def run(*args, **popen):
        app = subprocess.Popen([sys.executable, "-m", "glsim.cli", "preview", *args], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, env=env, **popen)
        try:
            yield app, env
        finally:
            if app.poll() is None:
                app.kill()
                app.wait()

    return run


REQUIRED = {"engine": "GLSIM_REQUIRE_ENGINE", "torch": "GLSIM_REQUIRE_TORCH"}   # marker → its tier's variable


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Under ``make test-engine`` (GLSIM_REQUIRE_ENGINE=1) a test marked ``engine`` that skips —
    the DIC environment absent or broken — fails instead, and under ``make test-torch``
    (GLSIM_REQUIRE_TORCH=1) one marked ``torch``: those tiers exist to run what the skip would
    leave out, and a skipped test there would pass CI without running anything."""
    outcome = yield
    report = outcome.get_result()
    for marker, var in REQUIRED.items():
        if report.skipped and os.environ.get(var) == "1" and item.get_closest_marker(marker) is not None:
            report.outcome = "failed"
            report.longrepr = f"{marker} test skipped under {var}=1: {report.longrepr}"
