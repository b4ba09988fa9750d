"""OpenGL backend: the only place where GL objects exist."""
