"""Exceptions and warnings shared by every stage."""


class GlsimError(Exception):
    """Base class of glsim's own errors."""


class SceneError(GlsimError, ValueError):
    """Bad scene input. The message names the key (or file) and says what is expected.

    ``key`` is the dotted scene path (``"cameras[1].fx"``) or a file name.
    """

    def __init__(self, key: str, problem: str, fix: str = ""):
        self.key = key
        msg = f"{key}: {problem}"
        if fix:
            msg += f" — {fix}"
        super().__init__(msg)


def interrupted(exc: BaseException) -> bool:
    """Whether ``exc`` is a KeyboardInterrupt (Ctrl-C, or a SIGTERM the command turns into one)
    or was raised while one was propagating: clean-up code that fails on the way out of an
    interrupt (a zip file closed in the middle of a member) must end the command as the
    interrupt, not as a traceback."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__context__
    return False


def check(ok: bool, key: str, problem: str, fix: str) -> None:
    """Raise :class:`SceneError` (``key``, ``problem``, ``fix``) unless ``ok``: the scene's and the
    calibration targets' value checks."""
    if not ok:
        raise SceneError(key, problem, fix)


class GLUnavailableError(GlsimError, RuntimeError):
    """No headless OpenGL (EGL) context could be made; backend="cpu" still works."""


class ShaderError(GlsimError, RuntimeError):
    """A GLSL program failed to compile or link; the message names file and line."""


class RendererClosedError(GlsimError, RuntimeError):
    """A :class:`glsim.render.Renderer` was asked to render after ``close()`` (or its ``with``
    block) released its backend."""


class RenderWarning(UserWarning):
    """A render went on but masked pixels or dropped elements (the message names them)."""
