"""GLSL sources of glsim (packaged as glsim.shaders; the source tree keeps them in shaders/)."""
