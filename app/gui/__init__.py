"""The capture station's desktop window (``kogei gui``): a PySide6 shell over the library calls the CLI uses.

Issue #7; DESIGN.md section 1 ("app: CLI, GUI").  One module per panel;
:mod:`app.gui.workers` runs every long task off the GUI thread.
"""
