"""The jobs the command line, the window, the batch runner, the demo and the report share.

Each module is one job, called the same way from every front end (the
``kogei`` command modules in :mod:`app.cli` only parse arguments, print and
choose exit codes):

* :mod:`app.workflows.calibration` -- the scanner calibration of a session (fit, install, read back);
* :mod:`app.workflows.process_session` -- a scan session's profiles to a registered, watertight mesh;
* :mod:`app.workflows.cloud_registration` -- point-cloud files registered and merged (``kogei register``);
* :mod:`app.workflows.chart` -- the colour chart of a RAW frame, located, sampled and checked;
* :mod:`app.workflows.spectral` -- per-pixel spectral weights from a frame and its chart (one chain);
* :mod:`app.workflows.identification` -- the material of each region of a spectral result;
* :mod:`app.workflows.materials` -- the display colour of a material preset;
* :mod:`app.workflows.scene_spec`, :mod:`app.workflows.scene_build` -- a scene description and its render job;
* :mod:`app.workflows.cloth_fit`, :mod:`app.workflows.cloth_scene` -- swatch sessions, the cloth fit, cloth scenes.

Import from the modules; this package imports nothing, so loading one job
never loads the others.
"""
