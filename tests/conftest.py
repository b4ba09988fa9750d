"""Shared fixtures: one EGL context for every GL test, its error flag checked around each."""
import pytest

from glsim.backends.gl.context import create_context


@pytest.fixture(scope="session")
def gl_ctx():
    ctx = create_context()
    yield ctx
    ctx.release()


@pytest.fixture(autouse=True)
def _gl_error_check(request):
    """GL tests start and end with GL_NO_ERROR (moderngl's own tests do the same)."""
    if request.node.get_closest_marker("gl") is None:
        yield
        return
    ctx = request.getfixturevalue("gl_ctx")
    assert ctx.error == "GL_NO_ERROR"
    yield
    assert ctx.error == "GL_NO_ERROR"
