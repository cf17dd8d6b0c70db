"""The root of kogei's input errors.

Every error that means "the input is wrong and the user can fix it" -- a
mesh with NaN vertices, a chart outside the frame, an unknown material, a
malformed session file -- derives from :class:`InputError`.  Its message is
one line that names the file, device or parameter and says what to do, so
the command line prints it as it is and exits with status 2, and the window
shows it in its log.  :class:`InputError` subclasses :class:`ValueError`, so
code that caught ``ValueError`` keeps working.

Examples
--------
>>> from processing.materials.presets import MaterialError
>>> issubclass(MaterialError, InputError) and issubclass(InputError, ValueError)
True
"""

from __future__ import annotations

__all__ = ["InputError"]


class InputError(ValueError):
    """Bad input the user can fix; the message is one line naming the input and the remedy."""
