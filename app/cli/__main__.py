"""``python -m app.cli ...``: the same as ``kogei ...``."""

import sys

from app.cli import main

sys.exit(main())
