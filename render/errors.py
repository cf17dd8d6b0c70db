"""Exceptions of the renderer.

Every error raised for bad input names the file or parameter at fault and
says what to do about it, so a command line or GUI can show the message as it
is.  The classes derive from :class:`ValueError` so that callers that only
know the standard library still catch them.

Examples
--------
>>> issubclass(MeshError, RenderInputError) and issubclass(RenderInputError, ValueError)
True
"""

from __future__ import annotations

from processing.errors import InputError

__all__ = ["RenderInputError", "MeshError", "MeshWarning", "RenderCancelled"]


class RenderInputError(InputError):
    """Bad input to the renderer (scene, camera, settings); the message names the parameter."""


class MeshError(RenderInputError):
    """A mesh file or mesh array that cannot be rendered; the message names the file."""


class MeshWarning(UserWarning):
    """A mesh was repaired on loading (degenerate triangles dropped, normals recomputed)."""


class RenderCancelled(Exception):
    """Raised by :func:`render.renderer.render` when its ``cancel()`` callback returned True."""
