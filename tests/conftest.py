"""Test-wide settings.

On CI (``CI`` set) hypothesis runs derandomized, so a landing is judged on a
reproducible set of examples; developers' runs keep exploring new random
examples, which is how edge cases (denormal cosines, ...) are found.
"""

from __future__ import annotations

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
