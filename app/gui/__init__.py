"""The capture station's desktop window (``kogei gui``): a PySide6 shell over the library calls the CLI uses.

What the window shows: README.md, "Capture station GUI".  One module per
panel; :mod:`app.gui.workers` runs every long task off the GUI thread.
"""
