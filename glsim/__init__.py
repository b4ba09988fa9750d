"""glsim: synthetic stereo-DIC images from finite-element results, on OpenGL shaders."""

__version__ = "0.1.0"
